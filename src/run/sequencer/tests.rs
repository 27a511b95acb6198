use super::settle::remaining_relaxation;
use super::steps::contact_from_line;
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
