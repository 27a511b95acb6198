//! The large-strain layer model's pieces the fit needs (docs/physics.md,
//! "Large strain"): the dimensionless groups a sample is looked up at in the
//! correction table, the warning when the table had to be left, and the model
//! error its intervals carry.

use sim::physics::Layer;
use sim::recording::Recording;

use super::Warning;
use super::full::{ModelParams, fe_layer};

/// Relative model error of the large-strain layer model (one standard
/// deviation): its recoveries on the test data's two neo-Hookean recordings
/// (E1 within 0.1–0.8 %, nu1 within 1.5–1.8 %, with the slip-aware twist)
/// and on a recording of the project's own large-strain reference off the
/// correction table's grid (E2/E1 1.5, nu1 and nu2 0.45: nu1 off by several
/// percent, the table's interpolation in the Poisson's ratios);
/// docs/physics.md, "Large strain".
pub(super) const MODEL_SD_E1: f64 = 0.015;
pub(super) const MODEL_SD_NU1: f64 = 0.04;

/// The dimensionless groups of the large-strain correction at approach `delta_mm`.
pub(super) fn groups(rec: &Recording, p: &ModelParams, layer: Layer, delta_mm: f64) -> fem::hyper::Groups {
    let ind = rec.meta.indenter;
    fem::hyper::Groups {
        e2_over_e1: ind.e_mpa / p.e1_mpa,
        nu1: p.nu1,
        nu2: ind.nu,
        h_over_r2: layer.thickness_mm / ind.r_mm,
        delta_over_r2: delta_mm.max(0.0) / ind.r_mm,
    }
}

/// A warning when the large-strain correction was taken outside its table (the
/// fitted groups or the sweep's depth beyond what was tabulated).
pub(super) fn warning(rec: &Recording, p: &ModelParams) -> Option<Warning> {
    let layer = fe_layer(rec).filter(|_| p.large_strain)?;
    let table = fem::hyper::LargeStrainTable::builtin().ok()?;
    let deepest = rec.samples.iter().map(|s| s.stage_mm - p.contact_offset_mm).fold(0.0, f64::max);
    let g = groups(rec, p, layer, deepest);
    let widest = rec.samples.iter().map(|s| s.rot_deg.abs()).fold(0.0, f64::max);
    let mu = p.contact_friction.unwrap_or(f64::INFINITY);
    let twist = table.at_groups(&g).frictional_twist_ratio(g.delta_over_r2, widest, mu);
    (table.gamma1_ratio(&g).clamped || twist.clamped).then(|| {
        Warning::new(
            "large_strain_extrapolated",
            format!(
                "the large-strain correction is tabulated for E2/E1 1-8, nu1 0.3-0.48, nu2 0.33-0.47, a gel as \
                 thick as the indenter's radius and twist / friction up to 50 deg; this fit (E2/E1 {:.2}, nu1 {:.3}, \
                 nu2 {:.2}, h/R2 {:.2}, deepest approach {:.2} R2, widest twist / friction {:.0} deg) takes it at the \
                 table's edge, so E1 and nu1 carry an unquantified model error",
                g.e2_over_e1,
                g.nu1,
                g.nu2,
                g.h_over_r2,
                g.delta_over_r2,
                widest / mu
            ),
        )
    })
}
