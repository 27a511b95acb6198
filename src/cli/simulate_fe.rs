//! `easycalib simulate --fidelity fe`: a recording from the project's own
//! large-strain finite-element reference (docs/physics.md, "Large strain"): a
//! flat gel layer bonded to its window, both bodies neo-Hookean, the normal
//! sweep in even stage steps to beta = 0.2 (frictionless pressing), then a
//! twist sweep there with Coulomb friction, taken to zero element size from
//! two meshes as the fit's large-strain table is, and the default sensor noise.

use fem::Material;
use fem::hyper::{SweepPlan, converged_layer_sweep};
use sim::physics::{Layer, LayerBase};
use sim::recording::{Metadata, Phase, Recording, Sample};

use super::CliError;
use super::SimulateArgs;
use super::calibrate::generator_config;

/// The sweeps the FE backend runs (as the finite-element recordings of the
/// project's test data: 30 stage steps to beta = 0.2, twists of 1° to 10°).
const NORMAL_STEPS: usize = 30;
const TWISTS_DEG: [f64; 11] = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0];
/// Seconds between samples in the written recording.
const SAMPLE_PERIOD_S: f64 = 0.8;

/// The recording `simulate --fidelity fe` writes for `args`.
pub fn fe_recording(args: &SimulateArgs) -> Result<Recording, CliError> {
    let h = args
        .layer
        .thickness_mm
        .ok_or_else(|| CliError::bad_input("--fidelity fe simulates a gel layer: give its --thickness-mm"))?;
    if args.layer.base.as_deref().is_some_and(|b| LayerBase::parse(b) != Some(LayerBase::Bonded)) {
        return Err(CliError::bad_input("--fidelity fe simulates a gel bonded to its window (--base bonded)"));
    }
    if args.elastomer.elastomer_r_mm.is_some_and(f64::is_finite) {
        return Err(CliError::bad_input("--fidelity fe simulates a flat gel: leave out --r1-mm (or give inf)"));
    }
    let cfg = generator_config(&args.elastomer, None)?;
    let layer = Layer::bonded(h);
    layer.validate().map_err(|e| CliError::bad_input(format!("--thickness-mm {h}: {e}")))?;
    let (gel, ind) = (cfg.pair.elastomer, cfg.pair.indenter);
    let materials = (Material { e_mpa: gel.e_mpa, nu: gel.nu }, Material { e_mpa: ind.e_mpa, nu: ind.nu });
    let plan = SweepPlan {
        beta: 0.2,
        normal_steps: NORMAL_STEPS,
        twists_deg: TWISTS_DEG.to_vec(),
        friction: sim::defaults::GEL_FRICTION,
    };
    eprintln!("simulating on the large-strain finite-element reference (two meshes, a few minutes)...");
    let sweep = converged_layer_sweep(h, materials.0, materials.1, ind.r_mm, &plan)
        .map_err(|e| CliError::bad_input(format!("cannot simulate on the FE reference: {e}")))?;
    let short = sweep.beta_reached < plan.beta - 0.005;
    if short {
        eprintln!(
            "warning: the finite-element reference stopped settling at beta = {:.3} (gamma2 {:.3} mm), short of \
             {}: the sweep ends there (a stiff indenter pressed deep into a thin gel is beyond its \
             contact iteration; docs/physics.md, \"Large strain\")",
            sweep.beta_reached,
            sweep.beta_reached * ind.r_mm,
            plan.beta
        );
    }
    let mut rng = sim::rng::Rng::seed_from(cfg.seed);
    let (sg, st) = (sim::defaults::GAMMA1_SIGMA_MM, sim::defaults::THETA1_SIGMA_DEG);
    let mut samples = Vec::new();
    let mut t = 0.0;
    for s in &sweep.normal {
        // No contact, no reading: the first sample is the stage zero itself.
        let g = if s.delta_mm > 0.0 { s.gamma1_mm + rng.gaussian(sg) } else { 0.0 };
        samples.push(Sample::new(t, Phase::Normal, s.delta_mm, 0.0, g, 0.0));
        t += SAMPLE_PERIOD_S;
    }
    let deepest = sweep.normal.last().ok_or_else(|| CliError::other("the FE sweep is empty"))?;
    for &(rot, theta) in &sweep.torsion_deg {
        let th = if rot > 0.0 { theta + rng.gaussian(st) } else { 0.0 };
        samples.push(Sample::new(t, Phase::Torsion, deepest.delta_mm, rot, deepest.gamma1_mm + rng.gaussian(sg), th));
        t += SAMPLE_PERIOD_S;
    }
    let mut meta = Metadata {
        sensor: Some("sim-fe".into()),
        indenter: ind,
        elastomer_r_mm: f64::INFINITY,
        layer: Some(layer),
        created: None,
        extra: vec![(
            "source".into(),
            format!(
                "easycalib large-strain FE reference (neo-Hookean, frictionless pressing, twist with Coulomb mu {}; \
                 gamma1 extrapolated to zero element size from two meshes); E1 {} MPa, nu1 {}, seed {}",
                sim::defaults::GEL_FRICTION,
                gel.e_mpa,
                gel.nu,
                cfg.seed
            ),
        )],
    };
    if short {
        meta.extra.push(("sim_beta_reached".into(), format!("{:.4}", sweep.beta_reached)));
    }
    Ok(Recording { meta, samples })
}
