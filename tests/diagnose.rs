//! Diagnosis on synthetic recordings with a known effect: the effect is named,
//! E1/nu1 move towards the truth, the residual drops to the noise floor;
//! clean controls name nothing; physics outside the library is `unexplained`;
//! sensor_gain is reported as degenerate.
//!
//! Recordings come from `sim::generator` with a sim profile (load until the
//! measured beta reaches 0.2, unload, re-approach, twist out and back; seeded
//! noise of 2 µm on gamma1 and 0.02 deg on theta1).

use easycalib::diagnosis::{DiagnoseOptions, Diagnosis, diagnose};
use sim::effects::{
    CommandedPose, SimProfile, adhesion, finite_thickness, partial_slip, sensor_gain, stage_backlash, thermal_drift,
    viscoelastic,
};
use sim::generator::{GeneratorConfig, generate};
use sim::physics::{Body, ContactPair};
use sim::recording::{Direction, Phase, Recording};

const E1: f64 = 0.33;
const NU1: f64 = 0.39;
const SIGMA_G: f64 = 0.002;
const SIGMA_T: f64 = 0.02;

fn pair() -> ContactPair {
    ContactPair { elastomer: Body::new(E1, NU1, 33.0), indenter: Body::new(1.1, 0.39, 5.0) }
}

/// A recording of the standard sweeps (the generator's procedure and noise)
/// on a rig with `profile`'s effects.
fn record(profile: &SimProfile, seed: u64) -> Recording {
    let cfg = GeneratorConfig { pair: pair(), profile: profile.clone(), seed, ..Default::default() };
    assert_eq!(cfg.noise.gamma1_sigma_mm, SIGMA_G);
    assert_eq!(cfg.noise.theta1_sigma_deg, SIGMA_T);
    generate(&cfg).unwrap()
}

fn run(name: &str, profile: &SimProfile, seed: u64) -> Diagnosis {
    let rec = record(profile, seed);
    let t0 = std::time::Instant::now();
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    let b = &d.baseline;
    let c = &d.corrected;
    println!(
        "{name:<18} seed {seed}: n={} named {:?} unexplained {} | E1 {:.4} -> {:.4} (truth {E1}, err {:+.2}% -> {:+.2}%) | nu1 {:.4} -> {:.4} (truth {NU1}, err {:+.2}% -> {:+.2}%) | rms normal {:.2} -> {:.2} µm hold {:.2} -> {:.2} µm torsion {:.4} -> {:.4} deg | noise {:.2} µm {:.4} deg | {:.0} ms",
        rec.samples.len(),
        d.effects,
        d.unexplained,
        b.e1_mpa,
        c.e1_mpa,
        (b.e1_mpa / E1 - 1.0) * 100.0,
        (c.e1_mpa / E1 - 1.0) * 100.0,
        b.nu1,
        c.nu1,
        (b.nu1 / NU1 - 1.0) * 100.0,
        (c.nu1 / NU1 - 1.0) * 100.0,
        b.rms.normal_um,
        c.rms.normal_um,
        b.rms.hold_um,
        c.rms.hold_um,
        b.rms.torsion_deg,
        c.rms.torsion_deg,
        d.noise.normal_um,
        d.noise.torsion_deg,
        t0.elapsed().as_secs_f64() * 1e3
    );
    println!("  {}", d.verdict);
    for c in &d.candidates {
        println!(
            "    {:<32} dchi2 {:>9.1} dBIC {:>9.1} sig {} vif {:?}",
            c.effects.join("+"),
            c.delta_chi2,
            c.delta_bic,
            c.significant,
            c.vif
        );
    }
    d
}

/// The effect is named alone, E1/nu1 end closer to the truth and within the
/// given bounds, and the residual ends near the noise floor.
fn assert_found(d: &Diagnosis, effect: &str, e1_tol: f64, nu1_tol: f64) {
    assert_eq!(d.effects, vec![effect], "{}", d.verdict);
    assert!(!d.unexplained);
    let (b, c) = (&d.baseline, &d.corrected);
    let err = |v: f64, t: f64| (v / t - 1.0).abs();
    assert!(
        err(c.e1_mpa, E1) + err(c.nu1, NU1) < err(b.e1_mpa, E1) + err(b.nu1, NU1),
        "correction does not move towards the truth: {}",
        d.verdict
    );
    assert!(err(c.e1_mpa, E1) < e1_tol, "E1 {} vs {E1}", c.e1_mpa);
    assert!(err(c.nu1, NU1) < nu1_tol, "nu1 {} vs {NU1}", c.nu1);
    assert!(c.rms.normal_um < 1.3 * d.noise.normal_um, "{}", d.verdict);
    assert!(c.rms.torsion_deg < 1.3 * d.noise.torsion_deg, "{}", d.verdict);
    // The truth lies inside the reported intervals.
    assert!(c.ci95.e1_mpa[0] <= E1 && E1 <= c.ci95.e1_mpa[1], "E1 ci {:?}", c.ci95.e1_mpa);
    assert!(c.ci95.nu1[0] <= NU1 && NU1 <= c.ci95.nu1[1], "nu1 ci {:?}", c.ci95.nu1);
}

fn param(d: &Diagnosis, effect: &str, name: &str) -> (f64, [Option<f64>; 2]) {
    let e = d.explanation.iter().find(|e| e.effect == effect).unwrap();
    let p = e.params.iter().find(|p| p.name == name).unwrap();
    (p.value, p.ci95)
}

fn covers(ci: [Option<f64>; 2], truth: f64) -> bool {
    ci[0].is_none_or(|lo| lo <= truth) && ci[1].is_none_or(|hi| truth <= hi)
}

#[test]
fn finite_thickness_is_named_and_h_recovered() {
    let p = SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: 5.0 }), ..Default::default() };
    let d = run("finite_thickness", &p, 11);
    assert_found(&d, "finite_thickness", 0.01, 0.03);
    let (h, ci) = param(&d, "finite_thickness", "h_mm");
    assert!(covers(ci, 5.0), "h {h} {ci:?}");
    assert!(!d.mismatch.is_empty(), "a 5 mm layer is not concealed");
}

#[test]
fn stage_backlash_is_named() {
    let p = SimProfile {
        stage_backlash: Some(stage_backlash::Params { b_mm: 0.008, engaged: true }),
        ..Default::default()
    };
    let d = run("stage_backlash", &p, 12);
    assert_found(&d, "stage_backlash", 0.01, 0.03);
    let (b, ci) = param(&d, "stage_backlash", "b_mm");
    assert!(covers(ci, 0.008), "b {b} {ci:?}");
}

#[test]
fn thermal_drift_is_named() {
    let p = SimProfile {
        thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 1.5e-4, vdot_mm_per_s2: 0.0 }),
        ..Default::default()
    };
    let d = run("thermal_drift", &p, 13);
    assert_found(&d, "thermal_drift", 0.01, 0.03);
    let (v, ci) = param(&d, "thermal_drift", "v_mm_per_s");
    assert!(covers(ci, 1.5e-4), "v {v} {ci:?}");
}

#[test]
fn partial_slip_is_named() {
    let p = SimProfile { partial_slip: Some(partial_slip::Params { mu: 0.4 }), ..Default::default() };
    let d = run("partial_slip", &p, 14);
    assert_found(&d, "partial_slip", 0.01, 0.03);
    let (mu, ci) = param(&d, "partial_slip", "mu");
    assert!(covers(ci, 0.4), "mu {mu} {ci:?}");
}

#[test]
fn viscoelastic_is_named() {
    let p = SimProfile {
        viscoelastic: Some(viscoelastic::Params { rho: 1.05, tau_s: 5.0, memory_n: 0.0 }),
        ..Default::default()
    };
    let d = run("viscoelastic", &p, 15);
    assert_found(&d, "viscoelastic", 0.01, 0.03);
    let (rho, ci) = param(&d, "viscoelastic", "rho");
    assert!(covers(ci, 1.05), "rho {rho} {ci:?}");
}

#[test]
fn adhesion_is_named() {
    let p = SimProfile { adhesion: Some(adhesion::Params { w_mj_m2: 80.0, eta: 3.0 }), ..Default::default() };
    let d = run("adhesion", &p, 16);
    assert_found(&d, "adhesion", 0.01, 0.03);
    let (w, ci) = param(&d, "adhesion", "w_mJ_m2");
    assert!(covers(ci, 80.0), "w {w} {ci:?}");
}

#[test]
fn clean_controls_name_nothing() {
    let mut named = 0;
    for seed in 21..25 {
        let d = run("clean", &SimProfile::default(), seed);
        assert!(!d.unexplained, "{}", d.verdict);
        if !d.effects.is_empty() {
            named += 1;
        }
        assert!((d.e1_mpa / E1 - 1.0).abs() < 0.01 && (d.nu1 / NU1 - 1.0).abs() < 0.03);
    }
    assert_eq!(named, 0);
}

#[test]
fn physics_outside_the_library_is_unexplained() {
    // A depth-dependent sensor nonlinearity: a ripple of the reading with depth.
    let mut rec = record(&SimProfile::default(), 31);
    for s in rec.samples.iter_mut().filter(|s| s.gamma1_mm != 0.0) {
        s.gamma1_mm += 0.006 * (2.0 * std::f64::consts::PI * s.gamma1_mm / 0.8).sin();
    }
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    println!("{}", d.verdict);
    assert!(d.unexplained, "{}", d.verdict);
    assert!(d.effects.is_empty());
    assert!(!d.remaining.is_empty() && d.remaining.iter().any(|m| m.phase.starts_with("normal")));
}

#[test]
fn sensor_gain_is_degenerate_not_named() {
    let p = SimProfile { sensor_gain: Some(sensor_gain::Params { g: 1.02 }), ..Default::default() };
    let d = run("sensor_gain", &p, 41);
    assert!(d.effects.is_empty(), "{}", d.verdict);
    let g = d.degenerate.iter().find(|g| g.effect == "sensor_gain").expect("sensor_gain degenerate");
    assert!(g.separate_by.is_some_and(|s| !s.is_empty()));
    // The gain error biases the baseline: the degeneracy is real, not a formality.
    assert!((d.baseline.nu1 / NU1 - 1.0).abs() > 0.03, "{}", d.baseline.nu1);
}

/// A recording the emulated rig made through its sensing chain (sensor gain
/// 0.99, seed 102, the standard sweeps and one `torsion_at_depth` the closed
/// loop ran; tests/data/rig/sensor_gain_after_torsion.csv): a layer fits it
/// 8 chi² units better than the true gain, beyond the BIC margin of two
/// effects with signatures (6) and within the significance guard (10.8).
/// A gain that no sweep of the run's own indenter can rule out stays
/// standing beside the layer (docs/diagnosis.md, "3. Explain"), so the
/// closed loop goes on to the rigid ball; it once named the layer here, with
/// nu1 7 % off.
#[test]
fn a_layer_does_not_rule_out_a_gain_on_a_margin_the_gain_can_hide_in() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rig/sensor_gain_after_torsion.csv");
    let rec = Recording::read_path(&path).unwrap();
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    println!("{}", d.verdict);
    assert!(d.effects.is_empty(), "named {:?}: {}", d.effects, d.verdict);
    let standing: Vec<&str> = d.ambiguous.iter().flat_map(|a| a.effects.iter().copied()).collect();
    assert!(standing.contains(&"sensor_gain") && standing.contains(&"finite_thickness"), "{standing:?}");
    let gain = d.ambiguous.iter().find(|a| a.effects == ["sensor_gain"]).unwrap();
    assert!(gain.delta_bic > 6.0, "the case this guards: the gain {:.1} behind", gain.delta_bic);
}

/// A recording the emulated rig made through its sensing chain (frame
/// compliance 0.004 mm/N, seed 1, the standard sweeps alone;
/// tests/data/rig/frame_compliance_layer_ahead.csv): a thin layer fits it 12
/// better in BIC than the true frame, beyond the significance guard's 10.8,
/// and the layer was named with nu1 7 % off (as once in CI). On these sweeps
/// the two trade places with the noise and the rig's timing by up to ~13
/// either way (docs/diagnosis.md, "3. Explain"): both stay standing.
#[test]
fn a_layer_does_not_rule_out_a_compliant_frame_on_the_standard_sweeps() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rig/frame_compliance_layer_ahead.csv");
    let rec = Recording::read_path(&path).unwrap();
    assert!(rec.samples.iter().all(|s| s.experiment.is_none()), "the fixture holds the standard sweeps alone");
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    println!("{}", d.verdict);
    assert!(d.effects.is_empty(), "named {:?}: {}", d.effects, d.verdict);
    assert!(!d.unexplained, "{}", d.verdict);
    let standing: Vec<&str> = d.ambiguous.iter().flat_map(|a| a.effects.iter().copied()).collect();
    assert_eq!(standing.first(), Some(&"finite_thickness"), "{standing:?}");
    let frame = d.ambiguous.iter().find(|a| a.effects == ["frame_compliance"]).expect("the frame stays standing");
    assert!(frame.delta_bic > 10.8, "the case this guards: the frame {:.1} behind", frame.delta_bic);
    // The frame's own correction is the one near the rig's truth (nu1 0.39).
    assert!((frame.nu1 / 0.39 - 1.0).abs() < 0.02, "frame's nu1 {}", frame.nu1);
}

/// The emulated rig's sensor read a 4.7 um contact as none (sensor gain 0.99,
/// seed 123, the standard sweeps; tests/data/rig/sensor_gain_unseen_contact.csv).
/// A zero in a recording with standard errors is "no contact seen" and weighs
/// nothing (docs/diagnosis.md, "1. Compare"): weighed as a measured depth it
/// held 157 of the truth's chi² and a layer was named with nu1 4 % off; now
/// the explanations the sweeps cannot rank, the gain among them, stand together.
#[test]
fn a_contact_the_sensor_did_not_see_is_not_read_as_a_depth() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rig/sensor_gain_unseen_contact.csv");
    let rec = Recording::read_path(&path).unwrap();
    let unseen = rec.samples.iter().filter(|s| s.gamma1_mm == 0.0 && s.stage_mm > 0.005).count();
    assert!(unseen >= 1, "the fixture holds a contact read as none");
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    assert!(d.effects.is_empty(), "named {:?}: {}", d.effects, d.verdict);
    assert!(!d.unexplained, "{}", d.verdict);
    let standing: Vec<&str> = d.ambiguous.iter().flat_map(|a| a.effects.iter().copied()).collect();
    assert!(standing.contains(&"sensor_gain"), "{standing:?}");
}

#[test]
fn profile_out_reproduces_the_recording() {
    let p = SimProfile {
        stage_backlash: Some(stage_backlash::Params { b_mm: 0.008, engaged: true }),
        ..Default::default()
    };
    let rec = record(&p, 51);
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    let text = d.profile.to_toml_string().unwrap();
    let prof = SimProfile::from_toml_str(&text).unwrap();
    assert!(prof.stage_backlash.is_some() && prof.material.is_some(), "{text}");
    // Re-simulate the recording's commanded history with the written profile.
    let cmds: Vec<CommandedPose> =
        rec.samples.iter().map(|s| CommandedPose { t_s: s.t_s, stage_mm: s.stage_mm, rot_deg: s.rot_deg }).collect();
    let again = sim::effects::simulate(pair(), &prof, &cmds).unwrap();
    let diffs: Vec<f64> = rec
        .samples
        .iter()
        .zip(&again)
        .filter(|(s, r)| s.gamma1_mm != 0.0 || r.gamma1_mm != 0.0)
        .map(|(s, r)| s.gamma1_mm - r.gamma1_mm)
        .collect();
    let rms = (diffs.iter().map(|v| v * v).sum::<f64>() / diffs.len() as f64).sqrt();
    assert!(rms < 1.3 * SIGMA_G, "re-simulated rms {rms}");
    // And without the effect it does not: the profile carries the physics.
    let bare = SimProfile { stage_backlash: None, ..prof };
    let again = sim::effects::simulate(pair(), &bare, &cmds).unwrap();
    let unload: Vec<f64> = rec
        .samples
        .iter()
        .zip(&again)
        .filter(|(s, _)| s.phase == Phase::Normal && s.dir == Some(Direction::Unload) && s.gamma1_mm != 0.0)
        .map(|(s, r)| s.gamma1_mm - r.gamma1_mm)
        .collect();
    let mean = unload.iter().sum::<f64>() / unload.len() as f64;
    assert!(mean > 0.003, "unload mean {mean}");
}

/// The concealed-data corpus committed under tests/data (written by
/// `cargo run -p sim --example make_corpus`): every case's effect is named,
/// or listed among explanations the sweeps cannot rank; its parameters'
/// intervals cover the truth; E1/nu1 move towards the truth; clean controls
/// name nothing; sensor_gain is never named and always reported degenerate.
#[test]
fn concealed_corpus() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let corpus: toml::Value = toml::from_str(&std::fs::read_to_string(dir.join("corpus.toml")).unwrap()).unwrap();
    let cases = corpus["case"].as_array().unwrap();
    assert!(cases.len() >= 10);
    for case in cases {
        let file = case["file"].as_str().unwrap();
        let effect = case["effect"].as_str().unwrap();
        let (e1, nu1) = (case["E1_MPa"].as_float().unwrap(), case["nu1"].as_float().unwrap());
        let rec = Recording::read_path(&dir.join(file)).unwrap();
        let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
        let (b, c) = (&d.baseline, &d.corrected);
        let err = |v: f64, t: f64| (v / t - 1.0) * 100.0;
        println!(
            "{file:<22} named {:?} ambiguous {:?} unexplained {} | E1 err {:+.2}% -> {:+.2}% | nu1 err {:+.2}% -> {:+.2}% | rms {:.2} -> {:.2} µm, {:.4} -> {:.4} deg (noise {:.2} µm)",
            d.effects,
            d.ambiguous.iter().map(|a| a.effects.join("+")).collect::<Vec<_>>(),
            d.unexplained,
            err(b.e1_mpa, e1),
            err(c.e1_mpa, e1),
            err(b.nu1, nu1),
            err(c.nu1, nu1),
            b.rms.normal_um,
            c.rms.normal_um,
            b.rms.torsion_deg,
            c.rms.torsion_deg,
            d.noise.normal_um
        );
        assert!(!d.unexplained, "{file}: {}", d.verdict);
        match effect {
            "clean" => assert!(d.effects.is_empty() && d.ambiguous.is_empty(), "{file}: {}", d.verdict),
            "sensor_gain" => {
                assert!(!d.effects.contains(&"sensor_gain"));
                assert!(d.degenerate.iter().any(|g| g.effect == "sensor_gain"), "{file}");
            }
            _ => {
                let named = d.effects.contains(&effect);
                let listed = d.ambiguous.iter().any(|a| a.effects.contains(&effect));
                assert!(named || listed, "{file}: {}", d.verdict);
                // The corrected intervals hold the truth; where the baseline was biased
                // beyond its own interval, the correction moves towards the truth.
                let inside = |ci: [f64; 2], t: f64| ci[0] <= t && t <= ci[1];
                assert!(inside(c.ci95.e1_mpa, e1) && inside(c.ci95.nu1, nu1), "{file}: {:?} {:?}", c.ci95, d.verdict);
                if !inside(b.ci95.e1_mpa, e1) || !inside(b.ci95.nu1, nu1) {
                    let total = |a: f64, b: f64| err(a, e1).abs() + err(b, nu1).abs();
                    assert!(total(c.e1_mpa, c.nu1) < total(b.e1_mpa, b.nu1), "{file}: {}", d.verdict);
                }
                if named {
                    let truth = case["profile"][effect].as_table().unwrap();
                    let e = d.explanation.iter().find(|e| e.effect == effect).unwrap();
                    for p in &e.params {
                        // The corpus's profiles leave the creep's memory at its default: a rested gel.
                        let t = truth.get(p.name).and_then(|v| v.as_float()).or((p.name == "memory_n").then_some(0.0));
                        let t = t.unwrap_or_else(|| panic!("{file}: the corpus has no {}", p.name));
                        assert!(covers(p.ci95, t), "{file}: {} = {} {:?} vs truth {t}", p.name, p.value, p.ci95);
                    }
                }
            }
        }
    }
}

/// Real sensor layers are 2-6 mm thick: at the standard sweep the layer is a
/// large effect. Diagnosis names it, fits h and recovers E1 and nu1 where the
/// paper's physics is far off. a/h at the deepest normal sample is printed:
/// the correction is asserted up to the thinnest layer here.
#[test]
fn thin_layers_are_corrected() {
    for (h, seed) in [(2.0, 63), (3.0, 61), (6.0, 62)] {
        let p = SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: h }), ..Default::default() };
        let rec = record(&p, seed);
        let top = rec.samples.iter().map(|s| s.stage_mm).fold(0.0, f64::max);
        let a = sim::effects::simulate(pair(), &p, &[CommandedPose { t_s: 0.0, stage_mm: top, rot_deg: 0.0 }]).unwrap()
            [0]
        .contact_radius_mm;
        let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
        let paper = easycalib::fit::fit_paper(&rec, &Default::default()).ok();
        println!(
            "h {h} mm (a/h {:.2} at the deepest sample): paper E1 {:?} nu1 {:?} | full E1 {:.4} nu1 {:.4} -> corrected E1 {:.4} nu1 {:.4} named {:?} | {}",
            a / h,
            paper.as_ref().map(|p| p.e1_mpa),
            paper.as_ref().map(|p| p.nu1),
            d.baseline.e1_mpa,
            d.baseline.nu1,
            d.corrected.e1_mpa,
            d.corrected.nu1,
            d.effects,
            d.verdict
        );
        for c in d.candidates.iter().filter(|c| c.significant) {
            println!("    {:<34} dchi2 {:>10.1} chi2/dof {:.2}", c.effects.join("+"), c.delta_chi2, c.chi2_per_dof);
        }
        assert_found(&d, "finite_thickness", 0.01, 0.03);
        let (hf, ci) = param(&d, "finite_thickness", "h_mm");
        assert!(covers(ci, h), "h {hf} {ci:?} vs {h}");
    }
}

/// The candidates fitted on all cores give exactly the serial diagnosis: the
/// same effects, the same numbers to the last bit, the same prose.
#[test]
fn parallel_diagnosis_equals_serial() {
    let backlash = SimProfile {
        stage_backlash: Some(stage_backlash::Params { b_mm: 0.008, engaged: true }),
        ..Default::default()
    };
    for (profile, seed) in [(SimProfile::default(), 3), (backlash, 4)] {
        let rec = record(&profile, seed);
        let serial = diagnose(&rec, &DiagnoseOptions { parallel: false, ..Default::default() }).unwrap();
        let parallel = diagnose(&rec, &DiagnoseOptions { parallel: true, ..Default::default() }).unwrap();
        assert_eq!(serial, parallel, "seed {seed}: the parallel diagnosis differs from the serial one");
        assert!(!serial.candidates.is_empty(), "seed {seed}: no candidate was tried");
    }
}
