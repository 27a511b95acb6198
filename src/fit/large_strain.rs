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
/// (E1 within 0.03–0.9 %, nu1 within 0.8–1.1 %, with the slip-aware twist
/// and the table on the 0.04 mm mesh)
/// and on a recording of the project's own large-strain reference off the
/// correction table's grid (E2/E1 1.5, nu1 and nu2 0.45: nu1 off by several
/// percent, the table's interpolation in the Poisson's ratios);
/// docs/physics.md, "Large strain".
pub(super) const MODEL_SD_E1: f64 = 0.015;
pub(super) const MODEL_SD_NU1: f64 = 0.04;

/// The further model error, relative, one standard deviation, per unit of
/// approach (delta/R2) the deepest sample lies past where the neo-Hookean
/// reference was followed for these materials (E1, nu1), where the ratios
/// follow the straight line through the table's last rows. Measured by
/// cutting the table short: its cases at E2/E1 1 and 2 cut at delta/R2
/// 0.30-0.50 and five recordings that reach 0.37-0.56 refitted
/// (docs/physics.md, "Past the table's depth"): E1 moved by 13 % and nu1 by
/// 25 % of the depth extended (RMS over 25 fits; up to 21 % and 51 %).
const EXTENDED_SD_E1_PER_R2: f64 = 0.15;
const EXTENDED_SD_NU1_PER_R2: f64 = 0.25;

/// The same per unit of approach past where the selective element's
/// reference stopped but within the fully integrated element's continuation
/// (fem/src/hyper/table.rs, `extend_with`), measured the same way: the
/// selective tables cut at 0.30-0.50 and continued, the five recordings
/// refitted (19 fits that reach past a cut): E1 moved by 6.1 % and nu1 by
/// 8.8 % of the depth continued (RMS; at most 10 % and 14 %), against 14 %
/// and 19 % for the straight line on the same fits (docs/physics.md, "Past
/// the table's depth").
const SPLICED_SD_E1_PER_R2: f64 = 0.061;
const SPLICED_SD_NU1_PER_R2: f64 = 0.088;

/// How far the sweep's deepest approach lies past the selective reference's
/// reach for the fitted materials, within the fully integrated continuation
/// and past that too (delta/R2; both 0 inside the selective reach): each
/// tabulated case the fitted materials interpolate between counts its own
/// shortfall, weighted by the magnitude of its interpolation weight
/// (`AtGroups::depths_past`).
pub(super) fn extended_depths(rec: &Recording, p: &ModelParams) -> [f64; 2] {
    let (Some(layer), Ok(table)) = (fe_layer(rec).filter(|_| p.large_strain), fem::hyper::LargeStrainTable::builtin())
    else {
        return [0.0; 2];
    };
    let deepest = rec.samples.iter().map(|s| s.stage_mm - p.contact_offset_mm).fold(0.0, f64::max);
    let g = groups(rec, p, layer, deepest);
    table.at_groups(&g).depths_past(g.delta_over_r2)
}

/// The large-strain model's own error (relative, one standard deviation, of
/// E1 and nu1) on recording `rec` at `p`: [`MODEL_SD_E1`], [`MODEL_SD_NU1`],
/// and in quadrature the errors of continuing the table in depth.
pub(super) fn model_sd(rec: &Recording, p: &ModelParams) -> [f64; 2] {
    let [spliced, past] = extended_depths(rec, p);
    [
        MODEL_SD_E1.hypot(SPLICED_SD_E1_PER_R2 * spliced).hypot(EXTENDED_SD_E1_PER_R2 * past),
        MODEL_SD_NU1.hypot(SPLICED_SD_NU1_PER_R2 * spliced).hypot(EXTENDED_SD_NU1_PER_R2 * past),
    ]
}

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
        let [continued, extended] = table.at_groups(&g).depths_past(g.delta_over_r2);
        let [sd_e1, sd_nu1] = model_sd(rec, p);
        Warning::new(
            "large_strain_extrapolated",
            format!(
                "the large-strain correction is tabulated for E2/E1 1-8, nu1 0.3-0.48, nu2 0.33-0.47, a gel as \
                 thick as the indenter's radius and twist / friction up to 50 deg, to the depth its reference \
                 followed; this fit (E2/E1 {:.2}, nu1 {:.3}, nu2 {:.2}, h/R2 {:.2}, deepest approach {:.2} R2, \
                 widest twist / friction {:.0} deg) takes it past the table's edge (its cases, weighted, \
                 continued {:.2} R2 on the fully integrated reference and {:.2} R2 on a straight line); the \
                 intervals carry a model error of {:.1} % in E1 and {:.1} % in nu1 (one standard deviation, the \
                 depth's extension included; not the other groups')",
                g.e2_over_e1,
                g.nu1,
                g.nu2,
                g.h_over_r2,
                g.delta_over_r2,
                widest / mu,
                continued,
                extended,
                sd_e1 * 100.0,
                sd_nu1 * 100.0
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(large_strain: bool) -> ModelParams {
        ModelParams { e1_mpa: 1.0, nu1: 0.48, contact_offset_mm: 0.0, contact_friction: Some(0.4), large_strain }
    }

    /// A sweep deeper than the reference was followed (the stiff indenter of
    /// the test data's tableI_4, E2/E1 4, to delta/R2 0.74 where the
    /// selective element's reference stopped at 0.55 and the fully
    /// integrated continuation at 0.69, the contact at the indenter's flank)
    /// carries the continuation's error and the straight line's on top of
    /// the model's, growing with the depth extended and named in the warning;
    /// the same sweep cut inside the table carries the model's error alone,
    /// and the linear model none of this.
    #[test]
    fn a_sweep_past_the_tables_depth_carries_the_extensions_error() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/fem-dev/linear/tableI_4_E2-4.0_nu2-0.40.csv");
        let deep = Recording::read_path(std::path::Path::new(path)).unwrap();
        let p = params(true);
        let [spliced, past] = extended_depths(&deep, &p);
        assert!(spliced > 0.1 && spliced < 0.2 && past > 0.02 && past < 0.1, "continued {spliced} R2, extended {past}");
        let [e1, nu1] = model_sd(&deep, &p);
        let expected = MODEL_SD_E1.hypot(SPLICED_SD_E1_PER_R2 * spliced).hypot(EXTENDED_SD_E1_PER_R2 * past);
        assert!((e1 - expected).abs() < 1e-12 && e1 > MODEL_SD_E1 && nu1 > MODEL_SD_NU1, "{e1} {nu1}");
        let w = warning(&deep, &p).expect("a warning past the table");
        assert!(w.message.contains(&format!("{:.1} % in E1", e1 * 100.0)), "{}", w.message);
        // Deeper still, more of it on the straight line: a wider error.
        let mut deeper = deep.clone();
        deeper.samples.iter_mut().for_each(|s| s.stage_mm *= 1.25);
        let [_, past_deeper] = extended_depths(&deeper, &p);
        assert!(past_deeper > past + 0.15 && model_sd(&deeper, &p)[0] > 1.5 * e1, "{past_deeper}");

        let mut shallow = deep.clone();
        shallow.samples.retain(|s| s.stage_mm < 2.0);
        assert_eq!(extended_depths(&shallow, &p), [0.0; 2]);
        assert_eq!(model_sd(&shallow, &p), [MODEL_SD_E1, MODEL_SD_NU1]);
        assert_eq!(extended_depths(&deep, &params(false)), [0.0; 2]);
    }
}
