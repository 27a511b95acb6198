//! The diagnosis on a declared layer: the effects that act outside the
//! contact (the rig's motion, frame and sensor) are refitted on the FE layer
//! model the fit ends on (docs/diagnosis.md, "On a declared layer"). Checked
//! on the dev set's independent finite-element recordings, which none of our
//! physics made, with a rig effect laid on them afterwards by its definition
//! alone: a frame drifting at v moves the true approach away from the
//! commanded stage by v t, so the stage a rig records is the recording's
//! less v t.

mod common;

use easycalib::diagnosis::{DiagnoseOptions, Diagnosis, diagnose};
use easycalib::fit::{FitOptions, calibrate};
use sim::recording::Recording;

struct Dev {
    name: String,
    rec: Recording,
    e1: f64,
    nu1: f64,
}

fn dev(set: &str) -> Vec<Dev> {
    common::fem_dev(set)
        .into_iter()
        .map(|(f, rec)| Dev {
            name: format!("{set}/{}", f[0]),
            rec,
            e1: f[1].parse().unwrap(),
            nu1: f[2].parse().unwrap(),
        })
        .collect()
}

/// `rec` as a rig whose frame drifts toward the gel at v mm/s records it: the commanded stage
/// is the true approach less the drift.
fn with_drift(d: &Dev, v_mm_per_s: f64) -> Recording {
    let mut rec = d.rec.clone();
    for s in &mut rec.samples {
        s.stage_mm -= v_mm_per_s * s.t_s;
    }
    rec
}

fn pct(v: f64, truth: f64) -> f64 {
    (v / truth - 1.0) * 100.0
}

fn report(what: &str, d: &Dev, dg: &Diagnosis, fit_e1: f64, fit_nu1: f64) {
    println!(
        "{what:<16} {:<44} fit E1 {:+6.2} % nu1 {:+6.2} % | diagnose {:?} E1 {:+6.2} % nu1 {:+6.2} % ambiguous {}",
        d.name,
        pct(fit_e1, d.e1),
        pct(fit_nu1, d.nu1),
        dg.effects,
        pct(dg.e1_mpa, d.e1),
        pct(dg.nu1, d.nu1),
        dg.ambiguous.len()
    );
}

/// A recording the layer model explains is left alone: nothing named, and
/// the estimate is the fit's own (the same numbers and intervals).
#[test]
fn the_dev_sets_recordings_name_nothing_and_agree_with_fit() {
    for d in dev("linear").iter().chain(&dev("nonlinear")) {
        let cal = calibrate(&d.rec, &FitOptions::default()).unwrap();
        let dg = diagnose(&d.rec, &DiagnoseOptions::default()).unwrap();
        report("clean", d, &dg, cal.full.e1_mpa, cal.full.nu1);
        assert!(dg.effects.is_empty(), "{}: {:?}", d.name, dg.effects);
        assert!(!dg.unexplained, "{}: {}", d.name, dg.verdict);
        assert!(dg.warnings.iter().any(|w| w.code == "contact_effects_not_searched"), "{}", d.name);
        assert_eq!((dg.e1_mpa, dg.nu1), (cal.full.e1_mpa, cal.full.nu1), "{}", d.name);
    }
}

/// A frame drifting toward the gel at 2 µm/s (a third of the library's
/// typical range) over the 33 s of a dev recording: the fit alone is biased
/// (printed: E1 -1.2 to -6.5 %, nu1 -1.4 to -5.3 %). Laid on the recordings,
/// this drift makes the recorded stage back off by 16 µm while the twist
/// sweep holds the depth, and a stage's play explains such a reversal as
/// well as the drift does; where the two rank within the ambiguity margin
/// nothing is named (4 of 10), and the estimate is the fit's. Otherwise the
/// diagnosis names the drift, names nothing else, and its correction
/// takes the estimate back to where the same recording without the drift
/// is fitted: within 1 % in E1 and 2 % in nu1 of the truth, beyond what the
/// layer model misses on that recording without the drift (tableI_3's -2 %;
/// docs/physics.md section 3), which no diagnosis of the rig can remove.
/// On the neo-Hookean recordings the clean fit's miss (E1 -0.8 and +0.1 %)
/// understates that: a free drift moves their estimate by up to 1.2 % in
/// either direction of the drift (to E1 +0.6 and +1.3 %, nu1 +0.4 and
/// -0.7 %), taking up part of what the large-strain model and the test
/// data's reference disagree on in the press. There the model's stated
/// error (`MODEL_SD_E1`, `MODEL_SD_NU1` in src/fit/large_strain.rs: 1.5 %
/// and 4 %, one standard deviation) stands for the miss when it is larger.
#[test]
fn a_drifting_frame_on_a_layer_is_named_and_corrected() {
    drift_is_named_and_corrected(0.002, &["linear", "nonlinear"], 6);
}

/// Drifting away from the gel. The fit alone takes the neo-Hookean
/// recordings' shortened sweeps for the linear model; the diagnosis tries
/// the other strain model once it has found the drift.
#[test]
fn a_frame_drifting_away_from_a_layer_is_named_and_corrected() {
    drift_is_named_and_corrected(-0.002, &["linear", "nonlinear"], 9);
}

/// The large-strain model's stated model error, percent (one standard
/// deviation; src/fit/large_strain.rs).
const LARGE_STRAIN_MODEL_E1_PCT: f64 = 1.5;
const LARGE_STRAIN_MODEL_NU1_PCT: f64 = 4.0;

fn drift_is_named_and_corrected(v_mm_per_s: f64, sets: &[&str], at_least: usize) {
    let mut named = 0;
    let mut total = 0;
    for d in sets.iter().flat_map(|s| dev(s)) {
        total += 1;
        let clean = calibrate(&d.rec, &FitOptions::default()).unwrap();
        let rec = with_drift(&d, v_mm_per_s);
        let cal = calibrate(&rec, &FitOptions::default()).unwrap();
        let dg = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
        report(&format!("drift {:+} um/s", v_mm_per_s * 1e3), &d, &dg, cal.full.e1_mpa, cal.full.nu1);
        assert!(
            dg.effects.iter().all(|&e| e == "thermal_drift" || e == "contact_offset"),
            "{}: {:?}",
            d.name,
            dg.effects
        );
        if !dg.effects.contains(&"thermal_drift") {
            continue;
        }
        named += 1;
        let found = &dg.explanation.iter().find(|e| e.effect == "thermal_drift").unwrap().params[0];
        // The bars (1 % in E1, 2 % in nu1) on top of what the layer
        // model misses on this recording without any drift.
        let (de, dn) = (pct(dg.e1_mpa, d.e1), pct(dg.nu1, d.nu1));
        let (mut me, mut mn) = (pct(clean.full.e1_mpa, d.e1).abs(), pct(clean.full.nu1, d.nu1).abs());
        if clean.full.large_strain {
            (me, mn) = (me.max(LARGE_STRAIN_MODEL_E1_PCT), mn.max(LARGE_STRAIN_MODEL_NU1_PCT));
        }
        println!(
            "    drift {:+.2} um/s found; E1 {de:+.2} % (allowed {:.2}), nu1 {dn:+.2} % (allowed {:.2})",
            found.value * 1e3,
            1.0 + me,
            2.0 + mn
        );
        assert!(de.abs() <= 1.0 + me && dn.abs() <= 2.0 + mn, "{}: E1 {de:+.2} %, nu1 {dn:+.2} %", d.name);
        let (ce, cn) = (dg.corrected.ci95.e1_mpa, dg.corrected.ci95.nu1);
        assert!(ce[0] <= d.e1 && d.e1 <= ce[1] && cn[0] <= d.nu1 && d.nu1 <= cn[1], "{}: {ce:?} {cn:?}", d.name);
    }
    println!("thermal_drift {v_mm_per_s} mm/s named in {named} of {total}");
    assert!(named >= at_least, "named in {named} of {total}");
}

/// A recording of our own layered rig (the linear FE layer model with
/// friction, `easycalib simulate --thickness-mm`) whose frame drifts toward
/// the gel at 0.5 µm/s over its 100 s: the fit alone is biased; the
/// diagnosis, which refits the friction and takes the friction correction
/// again where its explanation ends, names the drift and recovers the truth
/// within 1 % and 2 %. (The same model family as the diagnosis's: this
/// checks the passes and the wiring; the dev-set tests above check the
/// physics.)
#[test]
fn our_own_layered_rig_with_a_drifting_frame_is_diagnosed() {
    use sim::effects::thermal_drift;
    use sim::generator::{GeneratorConfig, LayeredTruth, generate_on};
    let mut cfg = GeneratorConfig::default();
    cfg.pair.elastomer.r_mm = f64::INFINITY;
    cfg.plan.normal_step_mm = 0.1;
    cfg.profile.thermal_drift = Some(thermal_drift::Params { v_mm_per_s: 5e-4, vdot_mm_per_s2: 0.0 });
    let layer = sim::physics::Layer::bonded(5.0);
    let (e1, nu1) = (cfg.pair.elastomer.e_mpa, cfg.pair.elastomer.nu);
    let law = easycalib::fit::fe_law::frictional_truth(layer, cfg.pair.indenter, e1, nu1, 0.4).unwrap();
    let rec = generate_on(&cfg, Some(&LayeredTruth { law, layer })).unwrap();
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    let dg = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    let (de, dn) = (pct(dg.e1_mpa, e1), pct(dg.nu1, nu1));
    println!(
        "{} samples over {:.0} s; fit E1 {:+.2} % nu1 {:+.2} %; diagnosis {:?} E1 {de:+.2} % nu1 {dn:+.2} %\n{}",
        rec.samples.len(),
        rec.samples.last().unwrap().t_s,
        pct(cal.full.e1_mpa, e1),
        pct(cal.full.nu1, nu1),
        dg.effects,
        dg.verdict
    );
    assert!(pct(cal.full.e1_mpa, e1).abs() > 2.0, "the drift biases the fit alone");
    assert!(dg.effects.contains(&"thermal_drift"), "{}", dg.verdict);
    assert!(de.abs() < 1.0 && dn.abs() < 2.0, "E1 {de:+.2} %, nu1 {dn:+.2} %");
    let found = dg.explanation.iter().find(|e| e.effect == "thermal_drift").unwrap().params[0].value;
    assert!((found / 5e-4 - 1.0).abs() < 0.2, "drift {found} mm/s");
}

/// A coarser or shorter sweep of the same rig is still a well-formed
/// recording, and gets an answer, not a refusal. Every dev recording with
/// every other normal step dropped (15 steps: the stiff pairs then pass
/// through the paper's 0.2-0.8 mm window in three, and the paper's method
/// is fitted on the narrowest widening that holds four, with a warning),
/// and the dev set's nu2 = 0.45 recording with its normal samples past the
/// 21st and its twists past the second lost (the friction is then
/// undetermined and fitted at about 34; the diagnosis's frictional presses
/// cycled in a load step there until a step that does not settle was
/// halved): fit and diagnosis answer, and the fit's intervals hold the
/// truth (printed).
#[test]
fn coarse_and_short_sweeps_of_the_dev_set_still_get_an_answer() {
    let (mut widened, mut covered, mut total) = (0, 0, 0);
    for d in dev("linear").iter().chain(&dev("nonlinear")) {
        let mut rec = d.rec.clone();
        let mut k = 0;
        rec.samples.retain(|s| {
            k += usize::from(s.phase == sim::recording::Phase::Normal);
            s.phase != sim::recording::Phase::Normal || k % 2 == 1
        });
        let cal = calibrate(&rec, &FitOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", d.name));
        let w = cal.warnings.iter().any(|w| w.code == "paper_window_widened");
        widened += usize::from(w);
        println!(
            "every other step  {:<44} E1 {:+6.2} % nu1 {:+6.2} % paper window {:?}{}",
            d.name,
            pct(cal.full.e1_mpa, d.e1),
            pct(cal.full.nu1, d.nu1),
            cal.paper.window_mm,
            if w { " (widened)" } else { "" }
        );
        assert_eq!(w, cal.paper.window_mm != [0.2, 0.8], "{}", d.name);
        let (ce, cn) = (cal.full.ci95.e1_mpa, cal.full.ci95.nu1);
        let holds = ce[0] <= d.e1 && d.e1 <= ce[1] && cn[0] <= d.nu1 && d.nu1 <= cn[1];
        covered += usize::from(holds);
        total += 1;
        if !holds {
            println!("  its intervals E1 {ce:.4?} nu1 {cn:.4?} miss the truth");
        }
    }
    assert!(widened >= 2, "only {widened} coarse sweeps needed the paper's window widened");
    // 95 % intervals: one miss in ten is within their rate (two or more
    // would happen by chance 9 % of the time). The miss is tableI_3, whose
    // full sweep already fits E1 1.55 standard errors low: half its steps
    // keep half the same noise.
    assert!(covered + 1 >= total, "the intervals held the truth on {covered} of {total}");
    let d = dev("linear").into_iter().find(|d| d.name.contains("nu2-0.45")).unwrap();
    let mut rec = d.rec.clone();
    let (mut steps, mut twists) = (0, 0);
    rec.samples.retain(|s| match s.phase {
        sim::recording::Phase::Normal => {
            steps += 1;
            steps <= 21
        }
        _ => {
            twists += usize::from(s.rot_deg != 0.0);
            twists <= 2
        }
    });
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    let dg = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    report("cut short", &d, &dg, cal.full.e1_mpa, cal.full.nu1);
    let (ce, cn) = (cal.full.ci95.e1_mpa, cal.full.ci95.nu1);
    assert!(ce[0] <= d.e1 && d.e1 <= ce[1] && cn[0] <= d.nu1 && d.nu1 <= cn[1], "{ce:?} {cn:?}");
    assert!(dg.e1_mpa.is_finite() && dg.nu1.is_finite());
}

/// More cases of the same kind: each dev recording with a second draw of its
/// own noise laid on it (gamma1 2 µm on every sample past the zero, theta1
/// 0.02° on the twists, as the set's README declares; seeds 1 and 2), so
/// twenty recordings that are the independent reference's physics at 1.4
/// times its noise. None of them is a rig effect: the diagnosis names
/// nothing on any (a spurious name would move the estimate off the fit's),
/// says nothing is unexplained, and its estimate is the fit's; the fit's
/// 95 % intervals hold the truth at their rate. Measured: 0 named of 20, 20
/// covered (six draws through the CLI: 0 named of 60, 59 covered;
/// docs/diagnosis.md, "On a declared layer").
#[test]
fn second_noise_draws_of_the_dev_set_name_nothing_and_keep_their_intervals() {
    let (mut covered, mut total) = (0, 0);
    for d in dev("linear").iter().chain(&dev("nonlinear")) {
        for seed in 1..=2u64 {
            let mut rng = sim::rng::Rng::seed_from(seed * 1000 + total as u64);
            let mut rec = d.rec.clone();
            for s in &mut rec.samples {
                if s.stage_mm > 0.0 {
                    s.gamma1_mm += rng.gaussian(0.002);
                }
                if s.phase == sim::recording::Phase::Torsion {
                    s.theta1_deg += rng.gaussian(0.02);
                }
            }
            let rec = Recording::parse(&rec.to_csv_string()).unwrap();
            let cal = calibrate(&rec, &FitOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", d.name));
            let dg = diagnose(&rec, &DiagnoseOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", d.name));
            report(&format!("second draw {seed}"), d, &dg, cal.full.e1_mpa, cal.full.nu1);
            assert!(dg.effects.is_empty(), "{} draw {seed}: {:?}\n{}", d.name, dg.effects, dg.verdict);
            assert!(!dg.unexplained, "{} draw {seed}: {}", d.name, dg.verdict);
            assert_eq!((dg.e1_mpa, dg.nu1), (cal.full.e1_mpa, cal.full.nu1), "{} draw {seed}", d.name);
            let (ce, cn) = (cal.full.ci95.e1_mpa, cal.full.ci95.nu1);
            let holds = ce[0] <= d.e1 && d.e1 <= ce[1] && cn[0] <= d.nu1 && d.nu1 <= cn[1];
            if !holds {
                println!("  its intervals E1 {ce:.4?} nu1 {cn:.4?} miss the truth");
            }
            covered += usize::from(holds);
            total += 1;
        }
    }
    // Both intervals of a 95 % pair hold together at about 0.95 at least:
    // 16 or more of 20 but by 0.3 % chance.
    assert!(covered >= 16, "the intervals held the truth on {covered} of {total}");
}
