//! A declared bonded layer is fitted with the project's FE reference (hemisphere
//! indenter on a bonded gel, Coulomb friction between them while pressing and
//! twisting): checked on the independent finite-element recordings of the dev
//! set, which it did not make: the linear recordings with the linear layer
//! model, the neo-Hookean ones with the large-strain model (the fit chooses).
//! Issue 13 asks for E1 within 1 % and nu1 within 2 %; what the models reach is
//! printed and asserted at the level they hold today, with intervals that cover
//! the truth (the model error is part of them).

mod common;

use std::path::PathBuf;

use easycalib::fit::{FitOptions, calibrate};
use sim::recording::Recording;

/// One dev-set recording fitted: its truth.csv row, the calibration, the truth
/// and the errors in percent.
struct Recovered {
    f: Vec<String>,
    cal: easycalib::fit::Calibration,
    e1: f64,
    nu1: f64,
    de: f64,
    dn: f64,
}

/// The fit's 95 % intervals hold the truth.
fn assert_covers(full: &easycalib::fit::FullFit, e1: f64, nu1: f64, what: &str) {
    let (ce, cn) = (full.ci95.e1_mpa, full.ci95.nu1);
    assert!(ce[0] <= e1 && e1 <= ce[1], "{what}: E1 interval {ce:?} misses {e1}");
    assert!(cn[0] <= nu1 && nu1 <= cn[1], "{what}: nu1 interval {cn:?} misses {nu1}");
}

fn recovered(set: &str) -> Vec<Recovered> {
    common::fem_dev(set)
        .into_iter()
        .map(|(f, rec)| {
            let (e1, nu1): (f64, f64) = (f[1].parse().unwrap(), f[2].parse().unwrap());
            let cal = calibrate(&rec, &FitOptions::default()).unwrap();
            let (de, dn) = ((cal.full.e1_mpa / e1 - 1.0) * 100.0, (cal.full.nu1 / nu1 - 1.0) * 100.0);
            Recovered { f, cal, e1, nu1, de, dn }
        })
        .collect()
}

#[test]
fn the_dev_sets_linear_recordings_are_recovered() {
    let (mut worst_e, mut worst_nu) = (0.0f64, 0.0f64);
    let (mut within_bars, mut apart2) = (0, 0.0);
    for Recovered { f, cal, e1, nu1, de, dn } in recovered("linear") {
        let full = &cal.full;
        println!(
            "{:32} E1 {:.4} [{:.4}, {:.4}] ({de:+.2} %)  nu1 {:.4} [{:.4}, {:.4}] ({dn:+.2} %)  mu {:.3?}  paper E1 {:+.1} % nu1 {:+.1} %",
            f[0],
            full.e1_mpa,
            full.ci95.e1_mpa[0],
            full.ci95.e1_mpa[1],
            full.nu1,
            full.ci95.nu1[0],
            full.ci95.nu1[1],
            full.contact_friction,
            (cal.paper.e1_mpa / e1 - 1.0) * 100.0,
            (cal.paper.nu1 / nu1 - 1.0) * 100.0,
        );
        let j = cal.model_choice.as_ref().unwrap();
        println!("    chi² linear {:.1}, large strain {:.1} (dof {}), by {}", j.chi2[0], j.chi2[1], j.dof, j.rule);
        assert_eq!(full.model, "layer-fe");
        assert_covers(full, e1, nu1, &f[0]);
        // The dev model's interface has Coulomb friction 0.4 (its README): the
        // torsion sweep's slip, with the normal sweep's grip, recovers it.
        let mu = full.contact_friction.unwrap();
        assert!((0.3..0.55).contains(&mu), "{}: friction {mu}", f[0]);
        worst_e = worst_e.max(de.abs());
        worst_nu = worst_nu.max(dn.abs());
        within_bars += usize::from(de.abs() < 1.0 && dn.abs() < 2.0);
        apart2 += mahalanobis2(full, e1, nu1);
    }
    println!("worst: E1 {worst_e:.2} %, nu1 {worst_nu:.2} %; {within_bars} of 8 within 1 % / 2 %");
    println!("truth from the fits, squared standard distances summed: {apart2:.2} (16 expected)");
    // Measured: E1 within 1.45 %, nu1 within 1.31 %, five of the eight inside
    // the 1 % / 2 % (tableI_1 +1.39 %, tableI_3 -1.45 %, tac3d_like_1
    // +1.004 % out). The dev set's noise alone scatters an exact model's E1
    // by 0.6-0.9 % (sd; examples/dev_noise_study.rs), so a 1 % bar on every
    // file is one to two standard deviations: what tells a better model
    // apart on eight files is whether the truth sits where the fits' own
    // uncertainties (the noise's and the model error they add, E1 se
    // 1.2-1.5 %, corr. with nu1 about -0.98) say. The squared standard
    // distance of the truth from each fit (two degrees of freedom) summed
    // over the eight is at most chi² with 16 if the intervals are honest
    // (less, as they carry the model error too): 16.97 measured. It was 51.9 before the layer
    // law was taken to zero element size and theta1 over the contact's
    // radius (docs/physics.md, "Mesh convergence" and "theta1 over the
    // contact"), when seven of the eight met the bars; 32.0 is chi²(16)'s 99 % point.
    assert!(worst_e < 2.0 && worst_nu < 2.0, "E1 {worst_e} %, nu1 {worst_nu} %");
    assert!(apart2 < 32.0, "the truth lies {apart2:.1} squared standard distances from the fits");
    assert!(within_bars >= 5, "{within_bars} of 8 within E1 1 %, nu1 2 %");
}

/// The squared standard (Mahalanobis) distance of (e1, nu1) from a fit's
/// estimate under its standard errors and their correlation.
fn mahalanobis2(full: &easycalib::fit::FullFit, e1: f64, nu1: f64) -> f64 {
    let (a, b, r) = ((full.e1_mpa - e1) / full.e1_se, (full.nu1 - nu1) / full.nu1_se, full.corr_e1_nu1);
    (a * a + b * b - 2.0 * r * a * b) / (1.0 - r * r)
}

/// The dev set's neo-Hookean recordings: the linear layer model leaves 14–16 µm
/// of systematic residuals and a nu1 19–27 % low; the fit takes the large-strain
/// model (the linear one times the neo-Hookean reference's ratios, tabulated in
/// dimensionless groups) because it fits better, and recovers the truth.
#[test]
fn the_dev_sets_nonlinear_recordings_are_recovered_at_large_strain() {
    let (mut worst_e, mut worst_nu) = (0.0f64, 0.0f64);
    for Recovered { f, cal, e1, nu1, de, dn } in recovered("nonlinear") {
        let full = &cal.full;
        println!(
            "{:32} {} E1 {:.4} [{:.4}, {:.4}] ({de:+.2} %)  nu1 {:.4} [{:.4}, {:.4}] ({dn:+.2} %)  rms {:.2} µm, {:.4}°  \
             warnings {:?}",
            f[0],
            full.model,
            full.e1_mpa,
            full.ci95.e1_mpa[0],
            full.ci95.e1_mpa[1],
            full.nu1,
            full.ci95.nu1[0],
            full.ci95.nu1[1],
            full.rms.normal_um,
            full.rms.torsion_deg,
            cal.warnings.iter().map(|w| w.code).collect::<Vec<_>>()
        );
        let j = cal.model_choice.as_ref().unwrap();
        println!("    chi² linear {:.1}, large strain {:.1} (dof {}), by {}", j.chi2[0], j.chi2[1], j.dof, j.rule);
        assert_eq!(full.model, "layer-fe-large-strain", "{}", f[0]);
        assert_covers(full, e1, nu1, &f[0]);
        assert!(!cal.warnings.iter().any(|w| w.code == "systematic_residuals"), "{}", f[0]);
        worst_e = worst_e.max(de.abs());
        worst_nu = worst_nu.max(dn.abs());
    }
    println!("worst: E1 {worst_e:.2} %, nu1 {worst_nu:.2} %");
    assert!(worst_e < LARGE_E1_PCT && worst_nu < LARGE_NU1_PCT, "E1 {worst_e} %, nu1 {worst_nu} %");
}

/// What the large-strain fit holds on the dev set's neo-Hookean recordings:
/// issue 13's 1 % and 2 %. Measured with the slip-aware twist
/// (fem/data/large_strain_slip.csv): E1 -0.81 % and +0.10 %, nu1 -1.49 % and
/// -1.80 %; before it, with the linear model's slip, E1 -1.71 % and -1.38 %.
const LARGE_E1_PCT: f64 = 1.0;
const LARGE_NU1_PCT: f64 = 2.0;

#[test]
fn diagnose_starts_from_the_layer_model_and_agrees_with_fit() {
    use easycalib::diagnosis::{DiagnoseOptions, diagnose};
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/fem-dev");
    // A linear recording is explained by the linear layer model, a neo-Hookean
    // one by the large-strain model: neither is left unexplained.
    for (file, explained) in
        [("linear/tableI_6_E2-2.0_nu2-0.35.csv", true), ("nonlinear/tableI_6_E2-2.0_nu2-0.35.csv", true)]
    {
        let rec = Recording::read_path(&dir.join(file)).unwrap();
        let cal = calibrate(&rec, &FitOptions::default()).unwrap();
        let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
        println!("{file}: {}", d.verdict);
        assert_eq!((d.e1_mpa, d.nu1), (cal.full.e1_mpa, cal.full.nu1));
        assert_eq!(d.corrected.ci95.e1_mpa, cal.full.ci95.e1_mpa);
        assert!(d.effects.is_empty());
        assert_eq!(d.unexplained, !explained, "{file}");
        assert!(d.warnings.iter().any(|w| w.code == "contact_effects_not_searched"));
    }
}

/// A recording of the project's own large-strain reference on the correction
/// table's grid (E2/E1 1, nu1 0.48, nu2 0.4; `easycalib simulate --fidelity fe
/// --thickness-mm 5 --r1-mm inf --e1-mpa 1 --nu1 0.48 --indenter-e-mpa 1
/// --indenter-nu 0.4 --seed 4`, on the reference's 0.06 mm mesh). Not an
/// independent check: it guards the choice between the two strain models. The
/// large-strain fit ended near nu1 = 0.5 here when its twist kept the linear
/// model's slip (0.494, E1 -2.9 %); with the slip-aware twist it gives nu1
/// 0.492, E1 -1.8 % (docs/physics.md, "The twist at large strain"), while the linear fit leaves chi² 361 against its
/// 45 at their common noise (1.81 µm; 48 degrees of freedom). The misfit
/// decides, not the bound.
#[test]
fn a_bound_does_not_hand_the_choice_to_a_model_that_misfits() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/fe-self/nh_E1-1.0_nu1-0.48_E2-1.0_nu2-0.40_seed4.csv");
    let rec = Recording::read_path(&path).unwrap();
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    let f = &cal.full;
    println!(
        "{} E1 {:.4} {:?} nu1 {:.4} {:?} rms {:.2} µm",
        f.model, f.e1_mpa, f.ci95.e1_mpa, f.nu1, f.ci95.nu1, f.rms.normal_um
    );
    let j = cal.model_choice.as_ref().unwrap();
    println!(
        "chi² linear {:.1}, large strain {:.1} (dof {}, noise {:.2} µm {:?}, {:.4}° {:?}), by {}",
        j.chi2[0],
        j.chi2[1],
        j.dof,
        j.gamma1_mm.sigma * 1e3,
        j.gamma1_mm.source,
        j.theta1_deg.sigma,
        j.theta1_deg.source,
        j.rule
    );
    assert_eq!(f.model, "layer-fe-large-strain");
    assert_eq!(j.rule, "misfit");
    assert_covers(f, 1.0, 0.48, "own large-strain recording");
    assert!(f.rms.normal_um < 2.5, "rms {}", f.rms.normal_um);
}

/// The layer fit reports its own second-order bias (Box's, `curvature_bias`):
/// at the dev set's noise it is a few hundredths of a percent, far below the
/// estimate's spread (measured: E1 -0.035 to +0.030 %, nu1 within 0.016 %).
#[test]
fn the_layer_fits_own_bias_is_reported_and_small() {
    for Recovered { f, cal, .. } in recovered("linear") {
        let full = &cal.full;
        let b = full.curvature_bias.unwrap_or_else(|| panic!("{}: no curvature bias reported", f[0]));
        let (be, bn) = (b.e1_mpa / full.e1_mpa * 100.0, b.nu1 / full.nu1 * 100.0);
        println!("{:32} Box's bias E1 {be:+.4} %, nu1 {bn:+.4} %, z0 {:+.2e} mm", f[0], b.contact_offset_mm);
        assert!(be.abs() < 0.1 && bn.abs() < 0.1, "{}: E1 {be} %, nu1 {bn} %", f[0]);
        assert!(!cal.warnings.iter().any(|w| w.code == "curvature_bias"), "{}", f[0]);
    }
}

/// Recordings of our own layer model (friction 0.4, a dev recording's truth and
/// schedule) with the dev set's noise, each noise draw z fitted as z and -z: the
/// pair's mean cancels the noise's odd orders, so its mean over pairs is the
/// estimator's bias. A first version of the noise study put 0.3-1.0 % of E1 on
/// that bias; it had used the same ten draws for every recording (their
/// schedules are the same), and mirrored, those very draws average to -0.04 %
/// (examples/dev_noise_study.rs). Measured here (the recordings with the
/// fit's mesh-limit term, 2026-12-03): E1 -0.07 ± 0.03 %, nu1 +0.05 ± 0.02 %,
/// against one fit's E1 spread of 0.97 %.
#[test]
#[ignore = "a noise study: about 40 layer fits (a minute in release)"]
fn the_layer_fit_is_unbiased_at_the_dev_sets_noise() {
    use fem::forward::Forward;
    use sim::recording::Phase;
    const FRICTION: f64 = 0.4;
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/fem-dev/linear");
    // splitmix64 + Box–Muller, fixed seed per recording.
    let gauss = |state: &mut u64| {
        let mut u = || {
            *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = *state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (a, b) = (u(), u());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    };
    let (mut pair_e, mut pair_n, mut plain_e) = (Vec::new(), Vec::new(), Vec::new());
    for (k, (file, e1, nu1)) in
        [("tableI_3_E2-3.0_nu2-0.40.csv", 1.0, 0.48), ("tac3d_like_1.csv", 0.33, 0.39)].into_iter().enumerate()
    {
        let rec = Recording::read_path(&dir.join(file)).unwrap();
        let ind = rec.meta.indenter;
        let forward = Forward::cached(rec.meta.layer.unwrap().thickness_mm, ind.e_mpa, ind.nu, ind.r_mm).unwrap();
        let model = forward.model(e1, nu1);
        // The mesh-limit term the fit's law adds (docs/physics.md, "Mesh
        // convergence"): without it these recordings were not made by the
        // law the fit assumes, and came back about 0.2 % high.
        let mesh = forward.tabulated_at(e1, nu1).unwrap();
        let stages: Vec<f64> = rec.samples.iter().map(|s| s.stage_mm).collect();
        let states = model.normal_path(&stages, FRICTION, stages.iter().copied().fold(0.0, f64::max) / 60.0).unwrap();
        let mut state = 7_000 + k as u64;
        for _ in 0..10 {
            let draws: Vec<(f64, f64)> = rec.samples.iter().map(|_| (gauss(&mut state), gauss(&mut state))).collect();
            let fit = |sign: f64| {
                let mut own = rec.clone();
                for ((s, st), (zg, zt)) in own.samples.iter_mut().zip(&states).zip(&draws) {
                    s.gamma1_mm = match st.gamma1_mm > 0.0 {
                        true => st.gamma1_mm + mesh.mesh_gamma1_mm(s.stage_mm).unwrap_or(0.0) + sign * 0.002 * zg,
                        false => 0.0,
                    };
                    s.theta1_deg = match s.phase {
                        Phase::Torsion => {
                            let twist = s.rot_deg.to_radians();
                            let t = model.theta1_rad(st, twist.abs(), FRICTION).map_or(0.0, f64::to_degrees);
                            t * twist.signum() + sign * 0.02 * zt
                        }
                        Phase::Normal => 0.0,
                    };
                }
                let full = calibrate(&own, &FitOptions::default()).unwrap().full;
                ((full.e1_mpa / e1 - 1.0) * 100.0, (full.nu1 / nu1 - 1.0) * 100.0)
            };
            let ((ep, np), (em, nm)) = (fit(1.0), fit(-1.0));
            pair_e.push((ep + em) / 2.0);
            pair_n.push((np + nm) / 2.0);
            plain_e.push(ep);
        }
    }
    let mean_se = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
        (m, sd / (v.len() as f64).sqrt(), sd)
    };
    let ((me, se_e, _), (mn, se_n, _), (_, _, sd_plain)) = (mean_se(&pair_e), mean_se(&pair_n), mean_se(&plain_e));
    println!(
        "20 antithetic pairs: E1 bias {me:+.3} ± {se_e:.3} %, nu1 {mn:+.3} ± {se_n:.3} % (one fit's E1 sd {sd_plain:.2} %)"
    );
    // The spread is what the noise allows; the bias is a small part of it.
    assert!(sd_plain > 0.3, "the draws did not scatter the fits: sd {sd_plain} %");
    assert!(me.abs() < 0.15 && mn.abs() < 0.15, "E1 bias {me} %, nu1 bias {mn} %");
    assert!(me.abs() < 0.2 * sd_plain, "E1 bias {me} % against a spread of {sd_plain} %");
}

/// A noiseless recording of one of our own layer models on a dev recording's
/// stage and twist schedule, at that recording's truth (friction 0.4 as in
/// the dev set): the linear layer model (its frictional press and twist) or
/// the large-strain one (the linear model times the neo-Hookean reference's
/// tabulated ratios, as the fit takes it). `written`: passed through the
/// recording writer and read back, so its readings carry the writer's
/// resolution (10 nm, 1e-5°) as a real file does; otherwise full precision.
fn own_noiseless(set: &str, file: &str, e1: f64, nu1: f64, large_strain: bool, written: bool) -> Recording {
    use easycalib::fit::{ModelParams, predict};
    use sim::recording::Phase;
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/fem-dev").join(set);
    let mut rec = Recording::read_path(&dir.join(file)).unwrap();
    let truth = ModelParams { e1_mpa: e1, nu1, contact_offset_mm: 0.0, contact_friction: Some(0.4), large_strain };
    let pred = predict(&rec, &truth).unwrap();
    for (s, p) in rec.samples.iter_mut().zip(&pred) {
        // The sensor's dead band: no contact seen reads exactly zero.
        s.gamma1_mm = if p.gamma1_mm > 0.0 { p.gamma1_mm } else { 0.0 };
        s.theta1_deg = if s.phase == Phase::Torsion { p.theta1_deg } else { 0.0 };
    }
    if written { Recording::parse(&rec.to_csv_string()).unwrap() } else { rec }
}

fn truths(set: &str) -> Vec<(String, f64, f64)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/fem-dev").join(set);
    std::fs::read_to_string(dir.join("truth.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[0].to_string(), f[1].parse().unwrap(), f[2].parse().unwrap())
        })
        .collect()
}

/// Fit a noiseless recording and print how the two models were judged.
fn fit_noiseless(rec: &Recording, opts: &FitOptions, what: &str, e1: f64, nu1: f64) -> (String, f64, f64) {
    let cal = calibrate(rec, opts).unwrap();
    let (f, j) = (&cal.full, cal.model_choice.as_ref().expect("a declared layer judges both models"));
    let (de, dn) = ((f.e1_mpa / e1 - 1.0) * 100.0, (f.nu1 / nu1 - 1.0) * 100.0);
    println!(
        "{what:44} {:22} E1 {de:+.4} %  nu1 {dn:+.4} %  chi² linear {:.3e} large {:.3e} (dof {}, noise {:.2e} mm {:?}, \
         {:.2e}° {:?}, by {})",
        f.model,
        j.chi2[0],
        j.chi2[1],
        j.dof,
        j.gamma1_mm.sigma,
        j.gamma1_mm.source,
        j.theta1_deg.sigma,
        j.theta1_deg.source,
        j.rule
    );
    (f.model.to_string(), de, dn)
}

/// Noiseless recordings of our own linear layer model on all eight dev
/// schedules, at full double precision: the fit keeps the linear model, with
/// the noise estimated from the residuals (`easycalib fit`; the truth within
/// 0.05 %) and with the dev set's noise given (`--noise-um 2` and 0.02°; within
/// 0.1 %, see below). Before the two models were judged at a common noise the
/// large-strain model won on four of these eight with the noise estimated and
/// on five with it given (E1 +6 to +44 %, nu1 on its bound): each model's
/// residuals were measured against their own second-difference floor, which is
/// numerical dust for the model that made the recording.
#[test]
fn noiseless_recordings_of_the_linear_model_pick_it_and_return_the_truth() {
    let given = FitOptions {
        full: easycalib::fit::FullOptions { gamma1_sigma_mm: Some(0.002), theta1_sigma_deg: Some(0.02) },
        ..Default::default()
    };
    let mut worst = [0.0f64; 2];
    let mut missed = Vec::new();
    for (file, e1, nu1) in truths("linear") {
        let rec = own_noiseless("linear", &file, e1, nu1, false, false);
        for (k, (opts, how)) in [(FitOptions::default(), "estimated"), (given, "given")].into_iter().enumerate() {
            let (model, de, dn) = fit_noiseless(&rec, &opts, &format!("{file} ({how} noise)"), e1, nu1);
            // The deferred friction correction's derivatives are finite
            // differences over 0.1 % of E1 (docs/physics.md, "In the fit"): with
            // the dev set's noise given as the weights, one schedule ends
            // 0.06 % off, within that step (tableI_2: its residuals are 0.10 µm
            // where the truth's are 0.016 µm; the choice is not involved).
            let bar = [0.05, 0.1][k];
            if model != "layer-fe" || de.abs() >= bar || dn.abs() >= bar {
                missed.push(format!("{file}, {how} noise: {model}, E1 {de:+.4} %, nu1 {dn:+.4} %"));
            }
            worst[k] = worst[k].max(de.abs()).max(dn.abs());
        }
    }
    println!("worst: {:.4} % (estimated noise), {:.4} % (given)", worst[0], worst[1]);
    assert!(missed.is_empty(), "{missed:#?}");
}

/// The same as written files (their readings rounded to the writer's 10 nm
/// and 1e-5°: the noise is then bounded below by that resolution or by a
/// hundredth of the large-strain fit's misfit) on two schedules, and
/// noiseless recordings of our own large-strain model (the table-scaled
/// linear model the fit uses) on the dev set's neo-Hookean schedules and two
/// linear ones: each picks the model that made it.
#[test]
fn noiseless_recordings_pick_the_model_that_made_them() {
    let some = |f: &String| f.starts_with("tableI_3") || f.starts_with("tac3d_like_1");
    for (file, e1, nu1) in truths("linear").into_iter().filter(|(f, ..)| some(f)) {
        let rec = own_noiseless("linear", &file, e1, nu1, false, true);
        let (model, de, dn) =
            fit_noiseless(&rec, &FitOptions::default(), &format!("{file} (linear, written)"), e1, nu1);
        assert_eq!(model, "layer-fe", "{file}");
        assert!(de.abs() < 0.05 && dn.abs() < 0.05, "{file}: E1 {de} %, nu1 {dn} %");
    }
    let others = |f: &String| f.starts_with("tableI_4") || f.starts_with("tac3d_like_2");
    let cases: Vec<(&str, (String, f64, f64))> = truths("nonlinear")
        .into_iter()
        .map(|t| ("nonlinear", t))
        .chain(truths("linear").into_iter().filter(|(f, ..)| others(f)).map(|t| ("linear", t)))
        .collect();
    for (set, (file, e1, nu1)) in cases {
        let rec = own_noiseless(set, &file, e1, nu1, true, true);
        let (model, de, dn) =
            fit_noiseless(&rec, &FitOptions::default(), &format!("{set}/{file} (large strain)"), e1, nu1);
        assert_eq!(model, "layer-fe-large-strain", "{set}/{file}");
        assert!(de.abs() < 0.5 && dn.abs() < 0.5, "{set}/{file}: E1 {de} %, nu1 {dn} %");
    }
}

/// Noiseless recordings of the project's own large-strain reference on two
/// nodes of the correction table (E2/E1 2 and 1, nu1 0.48, nu2 0.4, mu 0.4;
/// `fem/examples/own_noiseless.rs`: the calibration sweep to beta 0.2 and
/// twists 0-10 degrees, gamma1 extrapolated to zero element size from the
/// table's two meshes as the table is). Not an independent check (the tables
/// are built from this reference): it guards the slip-aware twist
/// (docs/physics.md, "The twist at large strain"). With the linear model's
/// slip under the stuck ratio the model's twist fell short of the
/// reference's by 0.095 and 0.072 degrees at 10 degrees and the fits ended at
/// E1 -0.77 and -1.49 %; measured now: within 0.004 and 0.014 degrees at
/// every twist, E1 -0.27 and -0.45 %, nu1 -0.33 and -0.04 %.
#[test]
fn the_large_strain_twist_follows_its_reference_under_friction() {
    use easycalib::fit::{FullOptions, ModelParams, fit_full, predict};
    use sim::recording::Phase;
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/fe-self");
    for file in ["nh_E1-1.0_nu1-0.48_E2-2.0_nu2-0.40_noiseless.csv", "nh_E1-1.0_nu1-0.48_E2-1.0_nu2-0.40_noiseless.csv"]
    {
        let rec = Recording::read_path(&dir.join(file)).unwrap();
        let truth = ModelParams {
            e1_mpa: 1.0,
            nu1: 0.48,
            contact_offset_mm: 0.0,
            contact_friction: Some(0.4),
            large_strain: true,
        };
        let pred = predict(&rec, &truth).unwrap();
        let worst = rec
            .samples
            .iter()
            .zip(&pred)
            .filter(|(s, _)| s.phase == Phase::Torsion)
            .map(|(s, q)| (s.theta1_deg - q.theta1_deg).abs())
            .fold(0.0, f64::max);
        let opts = FullOptions { gamma1_sigma_mm: Some(0.002), theta1_sigma_deg: Some(0.02) };
        let f = fit_full(&rec, &opts, ModelParams { e1_mpa: 0.9, nu1: 0.45, ..truth }).unwrap();
        let (de, dn) = ((f.e1_mpa - 1.0) * 100.0, (f.nu1 / 0.48 - 1.0) * 100.0);
        println!("{file}: twist at the truth within {worst:.4} deg; fit E1 {de:+.2} %, nu1 {dn:+.2} %");
        assert!(worst < 0.03, "{file}: the twist misses its reference by {worst} deg");
        assert!(de.abs() < 0.5 && dn.abs() < 0.5, "{file}: E1 {de:+.2} %, nu1 {dn:+.2} %");
    }
}

/// The bar (E1 within 1 %, nu1 within 2 %) across the indenters the
/// unseen finite-element cases span (E2 1-4 MPa, nu2 0.35-0.45), on
/// noiseless sweeps of the project's own neo-Hookean reference
/// (`fem/examples/own_noiseless.rs`, E1 1 MPa, nu1 0.48, a bonded 5 mm gel;
/// physics the fit does not run: it runs the linear layer law times ratios
/// tabulated at E2/E1 1, 2, 4, 8 and nu2 0.33, 0.4, 0.47), fitted and
/// diagnosed as `easycalib fit` and `diagnose` do. Against the stiff
/// indenters the reference stops settling before beta 0.2 (the E2 4 MPa
/// sweeps reach 0.115 and 0.134, the E2 3 MPa one 0.161), so those are
/// shorter sweeps. Measured: E1 -0.42 to +0.35 %, nu1 -1.07 to -0.07 %
/// (the diagnosis the same), every interval holding the truth.
#[test]
fn the_large_strain_fit_meets_the_bar_across_the_indenters() {
    use easycalib::diagnosis::{DiagnoseOptions, diagnose};
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/fe-self");
    for (e2, nu2) in
        [("1.0", "0.40"), ("1.0", "0.45"), ("2.0", "0.40"), ("3.0", "0.35"), ("4.0", "0.35"), ("4.0", "0.45")]
    {
        let file = format!("nh_E1-1.0_nu1-0.48_E2-{e2}_nu2-{nu2}_noiseless.csv");
        let rec = Recording::read_path(&dir.join(&file)).unwrap();
        let cal = calibrate(&rec, &FitOptions::default()).unwrap();
        let (de, dn) = ((cal.full.e1_mpa - 1.0) * 100.0, (cal.full.nu1 / 0.48 - 1.0) * 100.0);
        println!("{file}: {} beta {:.3} E1 {de:+.2} % nu1 {dn:+.2} %", cal.full.model, cal.full.beta);
        assert_eq!(cal.full.model, "layer-fe-large-strain", "{file}");
        assert!(de.abs() < 1.0 && dn.abs() < 2.0, "{file}: E1 {de:+.2} %, nu1 {dn:+.2} %");
        assert_covers(&cal.full, 1.0, 0.48, &file);
        let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
        let (de, dn) = ((d.e1_mpa - 1.0) * 100.0, (d.nu1 / 0.48 - 1.0) * 100.0);
        println!("  diagnose: E1 {de:+.2} % nu1 {dn:+.2} %");
        // (Its verdict is not asked for: without noise the model's own
        // 0.05 µm misfit is many times the 0.01 µm the recording resolves.)
        assert!(de.abs() < 1.0 && dn.abs() < 2.0, "{file}: diagnosed E1 {de:+.2} %, nu1 {dn:+.2} %");
    }
}

/// A gel declared sliding on its window (no grip at its base) is fitted on
/// that base. Three checks, the first two on physics the fit's model did not
/// make:
/// - `fem/tests/reference.rs` holds the FE model's sliding gel to the
///   analytical sliding layer (a different kernel) within 0.2 %;
/// - noiseless sweeps of the project's own neo-Hookean reference of a
///   sliding 5 mm gel to beta 0.05, 0.1, 0.15 and 0.18
///   (`BASE=sliding BETA=b fem/examples/own_noiseless.rs`, E1 1 MPa, nu1
///   0.48, E2 2 MPa, nu2 0.4): the large-strain correction is tabulated on
///   bonded gels only, so the fit misses it (printed: up to E1 +1.7 %, nu1
///   -17.7 %), says so, and its intervals, which carry the measured miss per
///   unit depth, hold the truth;
/// - a recording the linear FE model makes on a sliding gel (the generator's
///   schedule, the dev set's noise) is recovered to within its noise, and the
///   same recording declared bonded is not (nu1 off by more than 10 %): the
///   declared base is what the model takes.
#[test]
fn a_gel_sliding_on_its_window_is_fitted_on_that_base() {
    use sim::physics::{Body as Elastic, Layer, LayerBase};
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/fe-self");
    for beta in ["_beta0.05", "_beta0.1", "_beta0.15", ""] {
        let file = format!("nh_sliding_E1-1.0_nu1-0.48_E2-2.0_nu2-0.40{beta}_noiseless.csv");
        let rec = Recording::read_path(&dir.join(&file)).unwrap();
        assert_eq!(rec.meta.layer.map(|l| l.base), Some(LayerBase::Sliding));
        let cal = calibrate(&rec, &FitOptions::default()).unwrap();
        let (de, dn) = ((cal.full.e1_mpa - 1.0) * 100.0, (cal.full.nu1 / 0.48 - 1.0) * 100.0);
        let (ce, cn) = (cal.full.ci95.e1_mpa, cal.full.ci95.nu1);
        println!("{file}: {} E1 {de:+.2} % {ce:.3?} nu1 {dn:+.2} % {cn:.3?}", cal.full.model);
        assert!(cal.warnings.iter().any(|w| w.code == "sliding_base_approximate"), "{:?}", cal.warnings);
        assert_covers(&cal.full, 1.0, 0.48, &file);
    }

    let layer = Layer { base: LayerBase::Sliding, ..Layer::bonded(5.0) };
    let indenter = Elastic::new(2.0, 0.4, 5.0);
    let law = easycalib::fit::fe_law::frictional_truth(layer, indenter, 1.0, 0.48, 0.4).unwrap();
    let cfg = sim::generator::GeneratorConfig {
        pair: sim::physics::ContactPair { elastomer: Elastic::new(1.0, 0.48, f64::INFINITY), indenter },
        ..Default::default()
    };
    let rec = sim::generator::generate_on(&cfg, Some(&sim::generator::LayeredTruth { law, layer })).unwrap();
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    let (de, dn) = ((cal.full.e1_mpa - 1.0) * 100.0, (cal.full.nu1 / 0.48 - 1.0) * 100.0);
    println!("linear sliding recording: {} E1 {de:+.2} % nu1 {dn:+.2} %", cal.full.model);
    assert_eq!(cal.full.model, "layer-fe");
    assert!(de.abs() < 2.0 && dn.abs() < 3.0, "E1 {de:+.2} %, nu1 {dn:+.2} %");
    let mut bonded = rec.clone();
    bonded.meta.layer = Some(Layer::bonded(5.0));
    let cal = calibrate(&bonded, &FitOptions::default()).unwrap();
    let dn = (cal.full.nu1 / 0.48 - 1.0) * 100.0;
    println!("the same declared bonded: {} nu1 {dn:+.2} %", cal.full.model);
    assert!(dn.abs() > 10.0, "the declared base changed nothing (nu1 {dn:+.2} %)");
}

/// The fit iterates on a fast form of the layer model (each depth pressed
/// without friction, plus a friction correction taken between passes and
/// followed linearly; docs/physics.md). Where its passes end must be the
/// optimum of the model itself: searched again here directly on the exact
/// model (the frictional press followed along the approach, the twist's
/// slip), from the fit's answer, with the fit's noise floors as weights, on
/// every linear recording of the dev set. A correction frozen without its
/// derivatives put E1 1-2 % low, a standard error; the two optima agree to
/// a quarter of one, and the exact model's chi² at the fit's answer is
/// within 0.3 of its own minimum (measured: 0.03 % of E1 or less on five
/// recordings, 0.08-0.21 % on three, where chi² is flat along the E1-nu1
/// ridge to 0.11).
#[test]
fn the_passes_end_on_the_exact_layer_models_optimum() {
    use easycalib::fit::{ModelParams, predict};
    use easycalib::numerics::lm::{LmOptions, minimize};
    use sim::recording::Phase;
    for (f, rec) in common::fem_dev("linear") {
        let cal = calibrate(&rec, &FitOptions::default()).expect("a dev recording's fit");
        let fit = &cal.full;
        let (sg, st) = (fit.noise_floor.normal_um * 1e-3, fit.noise_floor.torsion_deg);
        let residuals = |p: &ModelParams, out: &mut Vec<f64>| -> bool {
            let Ok(pred) = predict(&rec, p) else { return false };
            out.clear();
            out.extend(rec.samples.iter().zip(&pred).map(|(s, q)| (s.gamma1_mm - q.gamma1_mm) / sg));
            let twists = rec.samples.iter().zip(&pred).filter(|(s, _)| s.phase == Phase::Torsion);
            out.extend(twists.map(|(s, q)| (s.theta1_deg - q.theta1_deg) / st));
            true
        };
        let p0 = fit.params();
        let mu0 = p0.contact_friction.expect("the linear layer fit carries the friction");
        // ln E1, logit(2 nu1), z0, ln mu.
        let params = |x: &[f64]| ModelParams {
            e1_mpa: x[0].exp(),
            nu1: 0.5 / (1.0 + (-x[1]).exp()),
            contact_offset_mm: x[2],
            contact_friction: Some(x[3].exp()),
            large_strain: p0.large_strain,
        };
        let x0 = [p0.e1_mpa.ln(), (2.0 * p0.nu1 / (1.0 - 2.0 * p0.nu1)).ln(), p0.contact_offset_mm, mu0.ln()];
        let mut r = Vec::new();
        assert!(residuals(&p0, &mut r), "{}: the exact model at the fit's answer", f[0]);
        let chi2_fit: f64 = r.iter().map(|v| v * v).sum();
        let opts = LmOptions { fd_step: 1e-6, ..LmOptions::default() };
        let exact = minimize(|x, r| residuals(&params(x), r), &x0, opts).expect("the exact model's search");
        let p = params(&exact.x);
        let (de, dn) = ((p0.e1_mpa - p.e1_mpa) / fit.e1_se, (p0.nu1 - p.nu1) / fit.nu1_se);
        println!(
            "{:32} fit E1 {:.5} nu1 {:.5} chi2 {chi2_fit:.2} | exact optimum E1 {:.5} nu1 {:.5} mu {:.3} chi2 {:.2} | \
             apart {de:+.3} and {dn:+.3} standard errors",
            f[0],
            p0.e1_mpa,
            p0.nu1,
            p.e1_mpa,
            p.nu1,
            p.contact_friction.unwrap_or(f64::NAN),
            exact.ssr
        );
        assert!(de.abs() < 0.25 && dn.abs() < 0.25, "{}: {de:+.3}, {dn:+.3} standard errors apart", f[0]);
        assert!(chi2_fit - exact.ssr < 0.3, "{}: chi2 {chi2_fit:.3} at the fit, {:.3} at the optimum", f[0], exact.ssr);
    }
}

/// A clean run of the emulated rig on the default 5 mm gel whose sweep
/// unloads back to a 1.6 mm contact (`unload_step_mm` 0.85, seed 4; its
/// stage zero moved as the run moves it; tests/data/rig/
/// layer_unload_small_contact.csv, written 2026-12-03 by the simulator
/// whose layer law is taken to zero element size and whose theta1 is taken
/// over the contact, as the fit's). The run made by the simulator before
/// (its gamma1 on the 0.06 mm mesh, theta1 over the nodes' edge) had fitted
/// from the paper's answer in another basin of the friction, E1 +1.6 %,
/// friction 0.46, chi²/dof 2.6, which the typical starts leave (a fit that
/// poor at the recording's errors looks further); neither it nor this run
/// does so now with those starts turned off. The run is recovered at its
/// noise: E1 within 0.5 %, chi²/dof near 1, the truth inside the intervals.
#[test]
fn a_run_unloading_back_to_a_small_contact_is_recovered_at_its_noise() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/rig/layer_unload_small_contact.csv");
    let rec = Recording::read_path(&path).unwrap();
    let full = calibrate(&rec, &FitOptions::default()).unwrap().full;
    let (de, dn) = (100.0 * (full.e1_mpa / 0.33 - 1.0), 100.0 * (full.nu1 / 0.39 - 1.0));
    let chi2 = full.chi2_dof.expect("weighted by the recording's standard errors");
    println!("E1 {de:+.2} %, nu1 {dn:+.2} %, friction {:?}, chi2/dof {chi2:.2}", full.contact_friction);
    assert!(de.abs() < 0.5 && dn.abs() < 1.0, "E1 {de:+.2} %, nu1 {dn:+.2} %");
    assert!(chi2 < 1.5, "chi2/dof {chi2}");
    assert_covers(&full, 0.33, 0.39, "the emulated run");
}
