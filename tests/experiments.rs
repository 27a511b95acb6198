//! The experiment steps on the synthetic generator (issue 14): each shows the
//! signature the effects library predicts, and the diagnosis of a recording
//! that holds one decides where the standard sweeps alone could not.

use easycalib::diagnosis::{DiagnoseOptions, diagnose};
use sim::effects::{SimProfile, finite_thickness, frame_compliance, thermal_drift, viscoelastic};
use sim::experiment::{Experiment, ExperimentSpec};
use sim::generator::{GeneratorConfig, NoiseSpec, generate};
use sim::recording::Recording;

fn noiseless() -> NoiseSpec {
    NoiseSpec { gamma1_sigma_mm: 0.0, theta1_sigma_deg: 0.0, ..NoiseSpec::default() }
}

/// gamma1 of the dwell's samples, in time order.
fn dwell(rec: &Recording) -> Vec<(f64, f64)> {
    rec.samples.iter().filter(|s| s.experiment == Some(Experiment::Dwell)).map(|s| (s.t_s, s.gamma1_mm)).collect()
}

/// docs/physics.md 2.3 and 2.9: during a hold after a load step, a creeping gel's gamma1 rises
/// and saturates (retardation time tau), under a drifting frame it rises in a
/// straight line (the gel's share of v), a clean rig's stays put.
#[test]
fn a_dwell_creeps_under_viscoelastic_and_drifts_linearly_under_thermal_drift() {
    let run = |profile: SimProfile| {
        let cfg = GeneratorConfig {
            noise: noiseless(),
            profile,
            // The gel has relaxed during the torsion sweep's hold: the dwell
            // follows a reload, whose last step loads the depth afresh.
            experiments: vec![
                ExperimentSpec::Reload { fraction: 0.5, steps: 3, cycles: 1 },
                ExperimentSpec::Dwell { hold_s: 60.0, every_s: 2.0 },
            ],
            ..GeneratorConfig::default()
        };
        dwell(&generate(&cfg).unwrap())
    };
    let clean = run(SimProfile::default());
    assert_eq!(clean.len(), 31);
    assert!(clean.iter().all(|p| p.1 == clean[0].1), "a clean hold reads one gamma1");
    assert!((clean[30].0 - clean[0].0 - 60.0).abs() < 1e-9);

    // Creep (tau 5 s): the first 20 s take nearly all of the rise, the last 20 s almost none.
    let visco = run(SimProfile {
        viscoelastic: Some(viscoelastic::Params { rho: 1.05, tau_s: 5.0, memory_n: 0.0 }),
        ..SimProfile::default()
    });
    let (early, late) = (visco[10].1 - visco[0].1, visco[30].1 - visco[20].1);
    assert!(early > 1e-3, "creep {early} mm over the first 20 s");
    assert!(late >= 0.0 && late < 0.05 * early, "creep {late} mm over the last 20 s vs {early}");

    // Drift (v 0.2 um/s): the frame brings the indenter v x 20 s closer in every
    // 20 s; the gel takes its share of that (the indenter the rest), the same
    // in every window to within the contact's slight stiffening.
    let v = 2e-4;
    let drift = run(SimProfile {
        thermal_drift: Some(thermal_drift::Params { v_mm_per_s: v, vdot_mm_per_s2: 0.0 }),
        ..SimProfile::default()
    });
    let rises: Vec<f64> = [(0, 10), (10, 20), (20, 30)].iter().map(|&(a, b)| drift[b].1 - drift[a].1).collect();
    for r in &rises {
        assert!(*r > 0.5 * v * 20.0 && *r < v * 20.0, "drift {r} mm over 20 s of {} mm", v * 20.0);
        assert!((r / rises[0] - 1.0).abs() < 0.02, "a linear drift: {rises:?}");
    }
}

/// Named, and among the alternatives listed as ambiguous.
fn verdict(rec: &Recording) -> (Vec<&'static str>, Vec<&'static str>) {
    let d = diagnose(rec, &DiagnoseOptions::default()).expect("diagnosis runs");
    let listed = d.ambiguous.iter().flat_map(|a| a.effects.iter().copied()).collect();
    (d.effects.clone(), listed)
}

/// A compliant frame and a thick layer both read as a depth-gain error in the
/// standard sweeps (docs/diagnosis.md: ambiguous). The torsion sweep at a
/// second, deeper depth separates them: the frame's error in the measured
/// depth grows with the force (beta^1.5), the layer's correction with the
/// contact radius over the thickness (beta^0.5). Over five seeds each, the
/// standard sweeps name the truth at most once, with the experiment at least
/// four times, and the diagnosis names nothing on clean recordings with it.
#[test]
fn torsion_at_a_second_depth_tells_a_compliant_frame_from_a_layer() {
    let second = ExperimentSpec::TorsionAtDepth { beta: 0.3, amplitude_deg: 8.0, step_deg: 0.4 };
    let cases = [
        (
            "frame_compliance",
            SimProfile {
                frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.003 }),
                ..SimProfile::default()
            },
        ),
        (
            "finite_thickness",
            SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: 100.0 }), ..SimProfile::default() },
        ),
    ];
    for (truth, profile) in cases {
        let (mut before, mut after) = (0, 0);
        for seed in 1..=5 {
            let cfg = GeneratorConfig { seed, profile: profile.clone(), ..GeneratorConfig::default() };
            let (named, listed) = verdict(&generate(&cfg).unwrap());
            assert!(named.contains(&truth) || listed.contains(&truth), "{truth} seed {seed}: {named:?} {listed:?}");
            before += usize::from(named == [truth]);
            let with = GeneratorConfig { experiments: vec![second], ..cfg };
            let (named, listed) = verdict(&generate(&with).unwrap());
            println!("{truth} seed {seed}: with the second depth named {named:?}, ambiguous {listed:?}");
            after += usize::from(named == [truth]);
        }
        println!("{truth}: named {before}/5 from the standard sweeps, {after}/5 with the second depth");
        assert!(before <= 1, "{truth}: the standard sweeps already decide ({before}/5)");
        assert!(after >= 4, "{truth}: the second depth decides only {after}/5");
    }
    for seed in 1..=3 {
        let cfg = GeneratorConfig { seed, experiments: vec![second], ..GeneratorConfig::default() };
        let (named, listed) = verdict(&generate(&cfg).unwrap());
        assert!(named.is_empty() && listed.is_empty(), "clean seed {seed}: {named:?} {listed:?}");
    }
}

/// The recording with experiment phases goes through the writer and the
/// reader unchanged, and the fit takes it.
#[test]
fn recordings_with_every_experiment_round_trip_and_fit() {
    let cfg = GeneratorConfig {
        experiments: vec![
            ExperimentSpec::Dwell { hold_s: 10.0, every_s: 1.0 },
            ExperimentSpec::Reload { fraction: 0.5, steps: 4, cycles: 2 },
            ExperimentSpec::TwistReversal { amplitude_deg: 3.0, step_deg: 0.5 },
            ExperimentSpec::TorsionAtDepth { beta: 0.1, amplitude_deg: 6.0, step_deg: 0.5 },
            ExperimentSpec::SlowRepeat { fraction: 0.5, steps: 3, dwell_s: 5.0 },
            ExperimentSpec::ApproachSpeed { fraction: 0.5, steps: 4, speed_mm_s: 0.1 },
        ],
        ..GeneratorConfig::default()
    };
    let rec = generate(&cfg).unwrap();
    // The approach's load moves carry their times (ramps the diagnosis replays).
    let timed: Vec<_> = rec.samples.iter().filter(|s| s.timing.move_s.is_some()).collect();
    assert_eq!(timed.len(), 4);
    assert!(timed.iter().all(|s| s.experiment == Some(Experiment::ApproachSpeed)));
    // The writer rounds (docs/recording-format.md); what it wrote reads back and writes again the same.
    let back = Recording::parse(&rec.to_csv_string()).unwrap();
    assert_eq!(Recording::parse(&back.to_csv_string()).unwrap().samples, back.samples);
    let labels = |r: &Recording| r.samples.iter().map(|s| (s.phase, s.experiment, s.dir)).collect::<Vec<_>>();
    assert_eq!(labels(&back), labels(&rec));
    // Every rig-only experiment; the operator-assisted ones make recordings of their own.
    for e in Experiment::ALL.into_iter().filter(|e| !matches!(e, Experiment::RigidBall | Experiment::SwapIndenter)) {
        assert!(rec.samples.iter().any(|s| s.experiment == Some(e)), "{e:?}");
    }
    let cal = easycalib::fit::calibrate(&back, &easycalib::fit::FitOptions::default()).expect("fits");
    let truth = cfg.pair.elastomer;
    assert!((cal.full.e1_mpa / truth.e_mpa - 1.0).abs() < 0.01, "E1 {}", cal.full.e1_mpa);
    assert!((cal.full.nu1 / truth.nu - 1.0).abs() < 0.03, "nu1 {}", cal.full.nu1);
}

/// docs/physics.md 2.7 and 2.8 on a twist reversal (+4 deg, through zero to
/// -4 deg and back, noise-free): a mount's lost motion `b` shifts theta1 by
/// one constant, H-scaled b, from the first reversal to the second and by
/// nothing before or after; slip at the contact's edge bends the response
/// instead, so its departure from the clean twist is not one step.
#[test]
fn a_twist_reversal_shows_lost_motion_as_one_step_and_slip_as_a_bend() {
    use sim::effects::{partial_slip, rotation_backlash};
    let reversal = |profile: SimProfile| {
        let cfg = GeneratorConfig {
            noise: noiseless(),
            profile,
            experiments: vec![ExperimentSpec::TwistReversal { amplitude_deg: 4.0, step_deg: 1.0 }],
            ..GeneratorConfig::default()
        };
        let rec = generate(&cfg).unwrap();
        rec.samples
            .iter()
            .filter(|s| s.experiment == Some(Experiment::Reversal))
            .map(|s| s.theta1_deg)
            .collect::<Vec<_>>()
    };
    let clean = reversal(SimProfile::default());
    assert_eq!(clean.len(), 16);
    let dev = |v: Vec<f64>| v.iter().zip(&clean).map(|(a, c)| a - c).collect::<Vec<f64>>();
    let b = 0.2;
    let lost = dev(reversal(SimProfile {
        rotation_backlash: Some(rotation_backlash::Params { b_deg: b, engaged: true }),
        ..SimProfile::default()
    }));
    // Out to +4 (samples 0-3) and after the turn at -4 (12-15): the clean twist.
    assert!(lost[..4].iter().chain(&lost[12..]).all(|d| d.abs() < 1e-9), "{lost:?}");
    // From +3 back to -4 (4-11): one step, theta1 per mount degree times b.
    let step = clean[0] * b;
    assert!(lost[4..12].iter().all(|d| (d - step).abs() < 1e-3 * step), "{lost:?} vs {step}");
    let slip =
        dev(reversal(SimProfile { partial_slip: Some(partial_slip::Params { mu: 0.5 }), ..SimProfile::default() }));
    let (lo, hi) = slip[4..12].iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), d| (l.min(*d), h.max(*d)));
    assert!(hi - lo > 0.02, "slip departs from the clean twist by {lo}..{hi} deg: not one step");
    assert!(slip[3] < -0.01, "slip lowers theta1 at +4 deg: {}", slip[3]);
}

/// Operator-assisted steps on the generator: the rigid ball's sweep is a
/// recording of its own with the ball in its header; the ball does not
/// deform, so a noise-free reading is the stage travel times the sensor's
/// gain (minus the frame's C F when the frame is compliant). The main
/// generator refuses such a step among its experiments, naming the way.
#[test]
fn a_rigid_ball_reads_the_stage_travel_times_the_gain() {
    use sim::effects::sensor_gain;
    use sim::generator::operator_recording;
    let ball = ExperimentSpec::RigidBall { r_mm: 5.0, travel_mm: 2.0, steps: 8 };
    let run = |profile: SimProfile| {
        let cfg = GeneratorConfig { noise: noiseless(), profile, ..GeneratorConfig::default() };
        operator_recording(&cfg, &ball, 500.0).unwrap()
    };
    let g = 0.98;
    let rec = run(SimProfile { sensor_gain: Some(sensor_gain::Params { g }), ..SimProfile::default() });
    assert_eq!(rec.samples.len(), 16);
    assert_eq!(rec.meta.indenter, ball.operator_indenter().unwrap());
    assert!(rec.meta.extra.iter().any(|(k, v)| k == "operator_step" && v == "rigid_ball"));
    for s in rec.samples.iter().filter(|s| s.stage_mm > 0.0) {
        assert_eq!(s.experiment, Some(Experiment::RigidBall));
        // Steel against a gel of 0.33 MPa: gamma2 / gamma1 = E1* / E2*, about
        // 2e-6 (the default pair: 0.39 MPa against 231 GPa plane strain).
        assert!((s.gamma1_mm - g * s.stage_mm).abs() < 5e-6 * s.stage_mm, "{s:?}");
    }
    // A compliant frame takes C F off the travel: more at the deeper points.
    let c = 0.01;
    let framed =
        run(SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: c }), ..SimProfile::default() });
    let lost: Vec<f64> = framed.samples.iter().take(8).map(|s| s.stage_mm - s.gamma1_mm).collect();
    assert!(lost.windows(2).all(|w| w[1] > w[0]) && lost[7] > 1e-3, "{lost:?}");
    let err = generate(&GeneratorConfig { experiments: vec![ball], ..GeneratorConfig::default() }).unwrap_err();
    assert!(err.to_string().contains("operator_recording"), "{err}");
}

/// A script may not list an operator-assisted step yet: the sequencer does
/// not prompt for a swap; the refusal names the step and why.
#[test]
fn a_script_refuses_operator_steps_naming_why() {
    let text = "[[experiment]]\nkind = \"rigid_ball\"\nr_mm = 5.0\ntravel_mm = 2.0\nsteps = 8\n";
    let e = easycalib::run::Script::from_toml(text).unwrap_err().to_string();
    assert!(e.contains("experiment 0 (rigid_ball)") && e.contains("operator"), "{e}");
}

/// gamma1 at each stop of `phase`'s samples, with their rig times.
fn stops(rec: &Recording, phase: Experiment) -> Vec<(f64, f64, f64)> {
    rec.samples.iter().filter(|s| s.experiment == Some(phase)).map(|s| (s.stage_mm, s.t_s, s.gamma1_mm)).collect()
}

fn creep() -> SimProfile {
    SimProfile {
        viscoelastic: Some(viscoelastic::Params { rho: 1.06, tau_s: 8.0, memory_n: 0.0 }),
        ..SimProfile::default()
    }
}

fn drift() -> SimProfile {
    SimProfile {
        thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 2.5e-3, vdot_mm_per_s2: 0.0 }),
        ..SimProfile::default()
    }
}

/// docs/experiments.md, `slow_repeat` (noise-free): out to half the travel,
/// then the top half of the loading branch again, waiting 0.01, 20 or 40 s
/// at each stop on top of the settling. A creeping gel (rho 1.06, tau 8 s)
/// moves toward its relaxed curve the longer it waits: shallower at the
/// bottom, just unloaded (it recovers), deeper at the top, just loaded; the
/// second 20 s add little (the creep saturates). Under a drifting frame
/// (2.5 um/s) the change is the drift's own, deeper everywhere and
/// proportional to the time elapsed: twice the wait, twice the change. A
/// clean rig reads the same at the same stage whatever the wait.
#[test]
fn a_slow_repeat_moves_toward_the_relaxed_curve_under_creep_and_by_the_elapsed_time_under_drift() {
    let run = |profile: SimProfile, dwell_s: f64| {
        let cfg = GeneratorConfig {
            noise: noiseless(),
            profile,
            experiments: vec![ExperimentSpec::SlowRepeat { fraction: 0.5, steps: 3, dwell_s }],
            ..GeneratorConfig::default()
        };
        stops(&generate(&cfg).unwrap(), Experiment::SlowRepeat)
    };
    let quick = run(SimProfile::default(), 0.01);
    assert_eq!(quick.len(), 4);
    for slow in [run(SimProfile::default(), 20.0), run(SimProfile::default(), 40.0)] {
        for (q, s) in quick.iter().zip(&slow) {
            assert_eq!(q.0, s.0, "the same stops");
            assert!((q.2 - s.2).abs() < 1e-12, "clean: {q:?} vs {s:?}");
        }
    }
    let change = |profile: SimProfile| {
        let (q, s20, s40) = (run(profile.clone(), 0.01), run(profile.clone(), 20.0), run(profile, 40.0));
        let d = |s: &[(f64, f64, f64)]| s.iter().zip(&q).map(|(a, b)| a.2 - b.2).collect::<Vec<f64>>();
        (d(&s20), d(&s40))
    };
    let (c20, c40) = change(creep());
    println!("creep: slow - quick at each stop, 20 s {c20:?}, 40 s {c40:?}");
    let largest = c20.iter().fold(0.0f64, |m, c| m.max(c.abs()));
    assert!(c20[0] < -1e-3, "creep: the bottom recovers after its unload: {} mm", c20[0]);
    assert!(c20[3] > 1e-3, "creep: the top reads deeper after the wait: {} mm", c20[3]);
    for (a, b) in c20.iter().zip(&c40) {
        assert!((b - a).abs() < 0.2 * largest, "creep saturates: 40 s {b} vs 20 s {a}");
    }
    let (d20, d40) = change(drift());
    println!("drift: slow - quick at each stop, 20 s {d20:?}, 40 s {d40:?}");
    for (k, (a, b)) in d20.iter().zip(&d40).enumerate() {
        // By stop k the slow run is (k + 1) waits later; the gel takes its share of v t.
        let extra = (k + 1) as f64 * 20.0;
        assert!(*a > 0.5 * 2.5e-3 * extra && *a < 2.5e-3 * extra, "drift at stop {k}: {a} mm over {extra} s");
        assert!((b / a - 2.0).abs() < 0.03, "drift scales with the time: {b} vs {a}");
    }
}

/// docs/experiments.md, `approach_speed` (noise-free): the top half of the
/// loading branch again with the stage at 1, 0.1 or 0.05 mm/s. Under a
/// drifting frame the change from the quick approach at each stop is the
/// drift's rate (the gel's share of it) times the extra time elapsed,
/// whatever the speed (change over extra time: one ratio at a stop for
/// both speeds). A creeping gel moves toward its relaxed curve during a
/// slower approach: the first stops, just after the unload, read shallower
/// (the gel recovered more), and the change over the extra time differs
/// from one speed to the other: it follows the loading history, not the clock.
#[test]
fn an_approach_at_another_speed_tells_creep_from_drift() {
    let run = |profile: SimProfile, speed_mm_s: f64| {
        let cfg = GeneratorConfig {
            noise: noiseless(),
            profile,
            experiments: vec![ExperimentSpec::ApproachSpeed { fraction: 0.5, steps: 4, speed_mm_s }],
            ..GeneratorConfig::default()
        };
        stops(&generate(&cfg).unwrap(), Experiment::ApproachSpeed)
    };
    let quick = run(SimProfile::default(), 1.0);
    assert_eq!(quick.len(), 5);
    let slow = run(SimProfile::default(), 0.05);
    // The same stops; the slow moves take their time (travel / speed).
    for k in 1..5 {
        assert_eq!(quick[k].0, slow[k].0);
        let step = quick[k].0 - quick[k - 1].0;
        assert!(step > 0.1, "a load step of {step} mm");
        let dt = (slow[k].1 - slow[k - 1].1) - (quick[k].1 - quick[k - 1].1);
        assert!((dt - step * (1.0 / 0.05 - 1.0)).abs() < 1e-6, "stop {k}: {dt} s more");
        assert!((quick[k].2 - slow[k].2).abs() < 1e-12, "clean: the same reading at the same stage");
    }
    let changes = |profile: SimProfile| {
        let q = run(profile.clone(), 1.0);
        [0.1, 0.05].map(|v| {
            let s = run(profile.clone(), v);
            s.iter().zip(&q).skip(1).map(|(a, b)| (a.2 - b.2, a.1 - b.1)).collect::<Vec<(f64, f64)>>()
        })
    };
    let [d10, d05] = changes(drift());
    println!("drift: slow - quick (mm, s) at 0.1 mm/s {d10:?}, at 0.05 mm/s {d05:?}");
    for ((g10, t10), (g05, t05)) in d10.iter().zip(&d05) {
        // The gel's share of the drift's 2.5 um/s, the same at one stop whatever the speed.
        let (r10, r05) = (g10 / t10, g05 / t05);
        assert!(r10 > 0.5 * 2.5e-3 && r10 < 2.5e-3, "drift: {r10} mm/s seen by the gel");
        assert!((r05 / r10 - 1.0).abs() < 0.01, "drift: {g10} mm over {t10} s, {g05} mm over {t05} s");
    }
    let [c10, c05] = changes(creep());
    println!("creep: slow - quick (mm, s) at 0.1 mm/s {c10:?}, at 0.05 mm/s {c05:?}");
    // The first stop, just unloaded, has recovered the more the slower the approach.
    assert!(c10[0].0 < -1e-3 && c05[0].0 < c10[0].0, "creep: {c10:?} {c05:?}");
    for ((g10, t10), (g05, t05)) in c10.iter().zip(&c05) {
        let (r10, r05) = (g10 / t10, g05 / t05);
        assert!((r05 - r10).abs() > 0.2 * r05.abs().max(r10.abs()), "creep follows the time: {r10} vs {r05} mm/s");
    }
}

#[path = "support/simrig.rs"]
mod simrig;

/// A stage whose driver cannot set its speed (the in-process simulated
/// rig's, like the GRBL driver, keeps `Axis::set_max_speed`'s "cannot"):
/// an `approach_speed` step stops the run by the one abort path with a
/// message naming the step and the stage, after its move out and before
/// any move at the wrong speed; the stage backs off. A slow repeat on the
/// same rig runs: its stops wait their dwell on the rig's clock.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_approach_at_another_speed_stops_on_a_stage_that_cannot_set_its_speed() {
    use easycalib::run::{Backoff, Culprit, RunStatus, Sequencer};
    use simrig::{SimRig, SimRigConfig, stepwise_script};
    let run = |spec: ExperimentSpec| async move {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("recording.csv");
        let rig = SimRig::new(SimRigConfig::default()).unwrap();
        let script = easycalib::run::Script { experiment: vec![spec], ..stepwise_script() };
        let mut seq = Sequencer::new(script, rig.stage(), rig.mount(), rig.gauge(), &path).unwrap();
        let out = seq.run().await;
        drop(seq);
        let rec = Recording::read_path(&path).unwrap();
        (out, rec)
    };
    let (out, rec) = run(ExperimentSpec::ApproachSpeed { fraction: 0.5, steps: 3, speed_mm_s: 0.1 }).await;
    let RunStatus::Aborted(info) = &out.status else { panic!("not aborted: {:?}", out.status) };
    assert_eq!(info.culprit, Culprit::Procedure);
    assert!(info.message.contains("approach_speed") && info.message.contains("cannot set its speed"), "{info}");
    assert!(matches!(info.backoff, Backoff::To(_)), "{info}");
    // Only the move out was sampled.
    let samples: Vec<_> = rec.samples.iter().filter(|s| s.experiment == Some(Experiment::ApproachSpeed)).collect();
    assert_eq!(samples.len(), 1);

    let (out, rec) = run(ExperimentSpec::SlowRepeat { fraction: 0.5, steps: 2, dwell_s: 5.0 }).await;
    assert_eq!(out.status, RunStatus::Completed, "{:?}", out.status);
    let slow: Vec<_> = rec.samples.iter().filter(|s| s.experiment == Some(Experiment::SlowRepeat)).collect();
    assert_eq!(slow.len(), 3);
    for s in slow {
        let (_, end) = s.timing.move_s.expect("a move before each stop");
        assert!(s.t_s - end >= 5.0, "waited {} s", s.t_s - end);
    }
}
