use super::settle::{mean, remaining_relaxation};
use super::steps::{Landing, contact_from_line, next_load_step};
use super::*;

#[test]
fn contact_line_extrapolates_to_zero() {
    let pts = [(12.05, 0.0), (12.10, 0.075), (12.15, 0.15), (12.20, 0.225)];
    let c = contact_from_line(&pts, 0.01).unwrap();
    assert!((c - 12.05).abs() < 1e-9, "{c}");
    assert_eq!(contact_from_line(&pts[..2], 0.01), None);
    assert_eq!(contact_from_line(&[(1.0, 0.5), (2.0, 0.2)], 0.01), None, "falling gamma1 is no contact line");
}

#[test]
fn relaxation_tail_is_extrapolated() {
    // Exponential approach to 1.0 with ratio 0.5 per window: 0.5, 0.75, 0.875 -> tail 0.125.
    assert!((remaining_relaxation(0.5, 0.75, 0.875) - 0.125).abs() < 1e-12);
    // Noise without a trend: just the last drift.
    assert!((remaining_relaxation(1.0, 1.002, 1.001) - 0.001).abs() < 1e-12);
    // Still speeding up: at least twice the larger drift.
    assert!((remaining_relaxation(0.0, 0.1, 0.3) - 0.4).abs() < 1e-12);
}

#[test]
fn abort_message_says_what_and_where_the_stage_went() {
    let a = AbortInfo {
        culprit: Culprit::Stage,
        message: "stage KDC101 SN 1: disconnected: pty closed".into(),
        backoff: Backoff::To(0.0),
    };
    assert_eq!(
        a.to_string(),
        "stage KDC101 SN 1: disconnected: pty closed; motion stopped; stage backed off to 0.000 mm"
    );
    let b = AbortInfo { backoff: Backoff::Failed("gone".into()), ..a };
    assert!(b.to_string().contains("COULD NOT back the stage off: gone"));
}

#[test]
fn a_mean_of_readings_averages_their_own_errors_down_but_not_the_shared_part() {
    // Four readings, each 2 um of its own noise and 1 um shared (the learnt
    // curvature's): the mean's error is sqrt(2^2 / 4 + 1^2) = sqrt(2) um.
    let r = |g: f64| GaugeReading::new(0.0, g, 0.0, 1.0).with_errors(5f64.sqrt() * 1e-3, 0.01).with_common_error(1e-3);
    let m = mean(&[r(0.100), r(0.102), r(0.101), r(0.103)]);
    assert!((m.gamma1_mm - 0.1015).abs() < 1e-12);
    let sd = m.gamma1_sd_mm.unwrap();
    assert!((sd - 2f64.sqrt() * 1e-3).abs() < 1e-12, "{sd}");
    assert_eq!(m.gamma1_common_sd_mm, Some(1e-3));
    // theta1 has no shared part: 0.01 / sqrt(4).
    assert!((m.theta1_sd_deg.unwrap() - 0.005).abs() < 1e-12);
}

#[test]
fn a_dead_band_zero_among_measured_readings_is_as_uncertain_as_they_are() {
    // The sensor reads a contact of a few um as none in some frames: the
    // zero takes the others' error instead of leaving the mean without one.
    let seen = GaugeReading::new(0.0, 0.008, 0.0, 0.2).with_errors(0.006, 0.05);
    let zero = GaugeReading::new(0.0, 0.0, 0.0, 0.0);
    let m = mean(&[seen, zero, seen, zero]);
    assert!((m.gamma1_mm - 0.004).abs() < 1e-12);
    assert!((m.gamma1_sd_mm.unwrap() - 0.003).abs() < 1e-12, "{:?}", m.gamma1_sd_mm);
    // No reading with an error: none for the mean either.
    assert_eq!(mean(&[zero, zero]).gamma1_sd_mm, None);
}

#[test]
fn a_contact_seen_in_some_frames_only_is_as_uncertain_as_its_frames_disagree() {
    // An adhesive gel's first contact on the emulated rig (500 mJ/m², seed 1):
    // two frames read 40.5 and 36.8 um, each to 1.5 um, and two read none
    // (the contact lifts the markers nearest its centre). The mean, 19.3 um,
    // is no reading of a 40 um contact to 1 um: its error is the frames'
    // spread over sqrt(4), 11.2 um.
    let seen = |g: f64| GaugeReading::new(0.0, g, 0.0, 0.75).with_errors(0.0015, 0.05);
    let zero = GaugeReading::new(0.0, 0.0, 0.0, 0.0);
    let m = mean(&[seen(0.0405), zero, seen(0.0368), zero]);
    assert!((m.gamma1_mm - 0.019325).abs() < 1e-12);
    let sd = m.gamma1_sd_mm.unwrap_or(f64::NAN);
    assert!((sd - 0.01118).abs() < 1e-5, "{sd}");
    // Frames that all see it keep their own error.
    let m = mean(&[seen(0.0405), seen(0.0368)]);
    assert!((m.gamma1_sd_mm.unwrap_or(f64::NAN) - 0.0015 / 2f64.sqrt()).abs() < 1e-12);
}

#[test]
fn loading_steps_finely_where_the_papers_window_is() {
    // The coarse design of examples/fast-script.toml.
    let n = crate::run::script::NormalSection { step_mm: 0.25, window_step_mm: 0.1, ..Default::default() };
    // Out of contact, and short of the window by more than a coarse step: coarse.
    assert_eq!(next_load_step(&n, -0.1, 0.0), n.step_mm);
    assert_eq!(next_load_step(&n, 0.01, 0.0075), n.step_mm);
    // The next coarse step would land in the window (0.2-0.8 mm of gamma1): fine.
    assert_eq!(next_load_step(&n, 0.1, 0.075), n.window_step_mm);
    assert_eq!(next_load_step(&n, 1.0, 0.75), n.window_step_mm);
    // Past the window: coarse again.
    assert_eq!(next_load_step(&n, 1.2, 0.85), n.step_mm);
    // Switched off.
    let off = crate::run::script::NormalSection { window_step_mm: 0.0, ..n };
    assert_eq!(next_load_step(&off, 1.0, 0.75), off.step_mm);
    // A script whose steps are finer everywhere keeps them.
    let fine = crate::run::script::NormalSection { step_mm: 0.05, ..n };
    assert_eq!(next_load_step(&fine, 1.0, 0.75), 0.05);
}

#[test]
fn the_loading_branch_lands_on_its_target_whatever_the_last_two_samples_slope() {
    // The default script near the top of the default run (target 0.2 within
    // 0.25 %, landing steps of at least 0.05 mm, coarse steps of 1.3 mm), as
    // in a run on a frame drifting 2.5 um/s that stopped at the depth limit:
    // beta 0.1992 at 4.3 mm past the contact, the mean slope 0.046 per mm.
    let land = Landing { target_beta: 0.2, tol: 0.0005, min_step_mm: 0.05 };
    let (beta, approach) = (0.1992, 4.3);
    // A healthy slope: the step that lands on the target (within the tolerance).
    let s = land.step(1.3, beta, 0.05, approach);
    assert!(s == 0.05 && beta + 0.05 * s <= 0.2 + 0.0025, "{s}");
    let s = land.step(1.3, 0.19, 0.05, approach);
    assert!((0.19 + 0.05 * s - 0.2).abs() <= 0.0005, "{s}");
    // A slope the drift turned negative, or flattened, must not let the
    // full 1.3 mm step run past the target (gamma1 would jump by ~1 mm).
    for local in [-0.01, 0.0, 1e-4, 0.01, f64::NAN] {
        let s = land.step(1.3, beta, local, approach);
        assert!(s <= 0.05 + 1e-12, "local slope {local}: step {s} mm");
        let s = land.step(1.3, 0.17, local, approach);
        // At the sweep's mean slope it lands within the tolerance.
        assert!((0.17 + 0.17 / approach * s - 0.2).abs() <= 0.0005, "local slope {local}: step {s} mm");
    }
    // Far from the target the step is the script's.
    assert_eq!(land.step(1.3, 0.05, 0.046, 1.0), 1.3);
    assert_eq!(land.step(1.3, 0.05, -0.02, 1.0), 1.3);
    // Before contact (no depth yet, no slope): the script's step.
    assert_eq!(land.step(0.05, 0.0, f64::NAN, -0.1), 0.05);
}

#[test]
fn phase_times_sum_a_phase_marked_twice_in_the_order_of_its_first_mark() {
    // The normal sweep's unloading after a torsion sweep at its top is marked `normal` again.
    let marks =
        [("homing", 0.0), ("approach", 30.0), ("normal", 36.0), ("torsion", 52.0), ("normal", 73.0), ("retract", 86.0)];
    let t = super::outcome::phase_times(&marks, 88.0);
    let got: Vec<(&str, f64)> = t.iter().map(|p| (p.phase, p.rig_time_s)).collect();
    assert_eq!(got, [("homing", 30.0), ("approach", 6.0), ("normal", 29.0), ("torsion", 21.0), ("retract", 2.0)]);
}
