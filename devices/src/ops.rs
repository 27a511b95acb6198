//! Small consumers of the motion traits that every sequencer step needs:
//! "move there, wait, check you arrived, and never leave the axis running
//! after a failure". They only see [`LinearStage`], so they work with any
//! driver (APT, GRBL, simulated) and are tested against mocks.

use std::time::Duration;

use thiserror::Error;

use crate::motion::{DeviceFault, FaultKind, LinearStage};

/// How a checked move behaves.
#[derive(Debug, Clone, PartialEq)]
pub struct MovePolicy {
    /// Wall-clock budget for the axis to arrive once the move has started.
    pub timeout: Duration,
    /// Total attempts to *start* an absolute move when the failure is
    /// transient (timeout, garbled reply). 1 = no retry.
    pub attempts: u32,
    /// Pause before the first retry; doubled before each further one.
    pub backoff: Duration,
    /// The move counts as arrived within this distance of the target, mm.
    pub tolerance_mm: f64,
}

impl Default for MovePolicy {
    fn default() -> Self {
        Self { timeout: Duration::from_secs(30), attempts: 3, backoff: Duration::from_millis(100), tolerance_mm: 0.002 }
    }
}

/// Why a checked move failed.
#[derive(Debug, Error)]
pub enum MoveError<E: DeviceFault> {
    #[error("target {target_mm} mm is outside the travel {min_mm}..{max_mm} mm; nothing was sent")]
    OutOfTravel { target_mm: f64, min_mm: f64, max_mm: f64 },
    #[error(transparent)]
    Device(E),
    #[error("move ended at {position_mm} mm, not at {target_mm} mm (tolerance {tolerance_mm} mm)")]
    Missed { target_mm: f64, position_mm: f64, tolerance_mm: f64 },
    #[error("{source}; stopping the axis afterwards failed too: {stop_error}")]
    StopFailed {
        #[source]
        source: E,
        stop_error: E,
    },
}

impl<E: DeviceFault> DeviceFault for MoveError<E> {
    fn kind(&self) -> FaultKind {
        match self {
            Self::OutOfTravel { .. } => FaultKind::Limit,
            Self::Device(e) | Self::StopFailed { source: e, .. } => e.kind(),
            Self::Missed { .. } => FaultKind::DeviceReported,
        }
    }
}

/// Faults worth another try: the command may simply not have got through.
fn transient(kind: FaultKind) -> bool {
    matches!(kind, FaultKind::Timeout | FaultKind::Protocol)
}

fn check_travel<E: DeviceFault>((min_mm, max_mm): (f64, f64), target_mm: f64) -> Result<(), MoveError<E>> {
    if !target_mm.is_finite() || target_mm < min_mm || target_mm > max_mm {
        return Err(MoveError::OutOfTravel { target_mm, min_mm, max_mm });
    }
    Ok(())
}

/// Wait for the move to end and check the arrival; on a failed wait, stop the
/// axis (unless the link is gone, when no command can reach it anyway).
async fn wait_and_check<S: LinearStage + ?Sized>(
    stage: &mut S,
    target_mm: f64,
    policy: &MovePolicy,
) -> Result<f64, MoveError<S::Error>> {
    match stage.wait_until_stopped(policy.timeout).await {
        Ok(p) if (p - target_mm).abs() <= policy.tolerance_mm => Ok(p),
        Ok(p) => Err(MoveError::Missed { target_mm, position_mm: p, tolerance_mm: policy.tolerance_mm }),
        Err(e) if e.kind() == FaultKind::Disconnected => Err(MoveError::Device(e)),
        Err(e) => match stage.stop().await {
            Ok(()) => Err(MoveError::Device(e)),
            Err(stop_error) => Err(MoveError::StopFailed { source: e, stop_error }),
        },
    }
}

/// Absolute move with travel check, transient-fault retries and arrival check.
///
/// Only the *start* is retried: re-sending an absolute target is harmless
/// even if the first command did get through, which is not true of a
/// relative move (see [`move_by_checked`]).
pub async fn move_to_checked<S: LinearStage + ?Sized>(
    stage: &mut S,
    target_mm: f64,
    policy: &MovePolicy,
) -> Result<f64, MoveError<S::Error>> {
    check_travel(stage.travel_mm(), target_mm)?;
    let attempts = policy.attempts.max(1);
    let mut pause = policy.backoff;
    for attempt in 1..=attempts {
        match stage.start_move_to_mm(target_mm).await {
            Ok(()) => break,
            Err(e) if attempt < attempts && transient(e.kind()) => {
                tokio::time::sleep(pause).await;
                pause = pause.saturating_mul(2);
            }
            Err(e) => return Err(MoveError::Device(e)),
        }
    }
    wait_and_check(stage, target_mm, policy).await
}

/// Relative move from the current position, with travel and arrival checks.
/// Never retried: a relative command that got through twice moves twice.
pub async fn move_by_checked<S: LinearStage + ?Sized>(
    stage: &mut S,
    delta_mm: f64,
    policy: &MovePolicy,
) -> Result<f64, MoveError<S::Error>> {
    let from = stage.position_mm().await.map_err(MoveError::Device)?;
    let target_mm = from + delta_mm;
    check_travel(stage.travel_mm(), target_mm)?;
    stage.start_move_by_mm(delta_mm).await.map_err(MoveError::Device)?;
    wait_and_check(stage, target_mm, policy).await
}

#[cfg(test)]
mod tests {
    use super::*;
    use async_trait::async_trait;
    use mockall::predicate::eq;
    use mockall::{Sequence, mock};

    use crate::motion::AxisStatus;

    #[derive(Debug, Clone, PartialEq, Error)]
    #[error("fake fault {0:?}")]
    struct Fault(FaultKind);

    impl DeviceFault for Fault {
        fn kind(&self) -> FaultKind {
            self.0
        }
    }

    mock! {
        Stage {}
        #[async_trait]
        impl LinearStage for Stage {
            type Error = Fault;
            fn travel_mm(&self) -> (f64, f64);
            async fn home(&mut self, timeout: Duration) -> Result<(), Fault>;
            async fn start_move_to_mm(&mut self, target_mm: f64) -> Result<(), Fault>;
            async fn start_move_by_mm(&mut self, delta_mm: f64) -> Result<(), Fault>;
            async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<f64, Fault>;
            async fn stop(&mut self) -> Result<(), Fault>;
            async fn position_mm(&mut self) -> Result<f64, Fault>;
            async fn status(&mut self) -> Result<AxisStatus, Fault>;
        }
    }

    fn policy() -> MovePolicy {
        MovePolicy {
            timeout: Duration::from_secs(5),
            attempts: 3,
            backoff: Duration::from_millis(10),
            tolerance_mm: 0.002,
        }
    }

    fn stage_with_travel() -> MockStage {
        let mut s = MockStage::new();
        s.expect_travel_mm().return_const((0.0, 12.0));
        s
    }

    #[tokio::test]
    async fn start_then_wait_in_order() {
        let mut s = stage_with_travel();
        let mut seq = Sequence::new();
        s.expect_start_move_to_mm().with(eq(2.5)).times(1).in_sequence(&mut seq).returning(|_| Ok(()));
        s.expect_wait_until_stopped()
            .with(eq(Duration::from_secs(5)))
            .times(1)
            .in_sequence(&mut seq)
            .returning(|_| Ok(2.5005));
        s.expect_stop().never();
        assert_eq!(move_to_checked(&mut s, 2.5, &policy()).await.unwrap(), 2.5005);
    }

    #[tokio::test]
    async fn out_of_travel_calls_nothing_that_moves() {
        // Any call besides travel_mm() would panic on the mock.
        let mut s = stage_with_travel();
        for bad in [12.01, -0.5, f64::NAN, f64::INFINITY] {
            let e = move_to_checked(&mut s, bad, &policy()).await.unwrap_err();
            assert_eq!(e.kind(), FaultKind::Limit, "{bad}");
        }
    }

    #[tokio::test]
    async fn transient_start_failures_retry_with_doubling_backoff() {
        let mut s = stage_with_travel();
        let mut seq = Sequence::new();
        s.expect_start_move_to_mm().times(1).in_sequence(&mut seq).returning(|_| Err(Fault(FaultKind::Timeout)));
        s.expect_start_move_to_mm().times(1).in_sequence(&mut seq).returning(|_| Err(Fault(FaultKind::Protocol)));
        s.expect_start_move_to_mm().times(1).in_sequence(&mut seq).returning(|_| Ok(()));
        s.expect_wait_until_stopped().times(1).in_sequence(&mut seq).returning(|_| Ok(4.0));
        let t0 = std::time::Instant::now();
        let quick = MovePolicy { backoff: Duration::from_millis(2), ..policy() };
        assert_eq!(move_to_checked(&mut s, 4.0, &quick).await.unwrap(), 4.0);
        // 2 ms, then doubled to 4 ms, of backoff before the third attempt (a lower bound only).
        assert!(t0.elapsed() >= Duration::from_millis(6), "{:?}", t0.elapsed());
    }

    #[tokio::test]
    async fn retries_are_bounded_and_return_the_last_fault() {
        let mut s = stage_with_travel();
        s.expect_start_move_to_mm().times(3).returning(|_| Err(Fault(FaultKind::Timeout)));
        s.expect_wait_until_stopped().never();
        let quick = MovePolicy { backoff: Duration::from_millis(1), ..policy() };
        let e = move_to_checked(&mut s, 1.0, &quick).await.unwrap_err();
        assert!(matches!(e, MoveError::Device(Fault(FaultKind::Timeout))), "{e}");
    }

    #[tokio::test]
    async fn permanent_start_failures_are_not_retried() {
        for kind in [FaultKind::Limit, FaultKind::DeviceReported, FaultKind::Disconnected] {
            let mut s = stage_with_travel();
            s.expect_start_move_to_mm().times(1).returning(move |_| Err(Fault(kind)));
            s.expect_wait_until_stopped().never();
            s.expect_stop().never();
            let e = move_to_checked(&mut s, 1.0, &policy()).await.unwrap_err();
            assert_eq!(e.kind(), kind);
        }
    }

    #[tokio::test]
    async fn failed_wait_stops_the_axis_then_reports_the_wait_fault() {
        let mut s = stage_with_travel();
        let mut seq = Sequence::new();
        s.expect_start_move_to_mm().times(1).in_sequence(&mut seq).returning(|_| Ok(()));
        s.expect_wait_until_stopped().times(1).in_sequence(&mut seq).returning(|_| Err(Fault(FaultKind::Timeout)));
        s.expect_stop().times(1).in_sequence(&mut seq).returning(|| Ok(()));
        let e = move_to_checked(&mut s, 3.0, &policy()).await.unwrap_err();
        assert!(matches!(e, MoveError::Device(Fault(FaultKind::Timeout))), "{e}");
    }

    #[tokio::test]
    async fn disconnected_wait_does_not_try_to_stop() {
        let mut s = stage_with_travel();
        s.expect_start_move_to_mm().returning(|_| Ok(()));
        s.expect_wait_until_stopped().times(1).returning(|_| Err(Fault(FaultKind::Disconnected)));
        s.expect_stop().never();
        let e = move_to_checked(&mut s, 3.0, &policy()).await.unwrap_err();
        assert_eq!(e.kind(), FaultKind::Disconnected);
    }

    #[tokio::test]
    async fn failing_stop_keeps_both_faults() {
        let mut s = stage_with_travel();
        s.expect_start_move_to_mm().returning(|_| Ok(()));
        s.expect_wait_until_stopped().returning(|_| Err(Fault(FaultKind::DeviceReported)));
        s.expect_stop().times(1).returning(|| Err(Fault(FaultKind::Timeout)));
        let e = move_to_checked(&mut s, 3.0, &policy()).await.unwrap_err();
        assert_eq!(e.kind(), FaultKind::DeviceReported);
        match e {
            MoveError::StopFailed { source, stop_error } => {
                assert_eq!(source, Fault(FaultKind::DeviceReported));
                assert_eq!(stop_error, Fault(FaultKind::Timeout));
            }
            other => panic!("{other}"),
        }
    }

    #[tokio::test]
    async fn arrival_outside_tolerance_is_missed() {
        let mut s = stage_with_travel();
        s.expect_start_move_to_mm().returning(|_| Ok(()));
        s.expect_wait_until_stopped().returning(|_| Ok(2.99));
        s.expect_stop().never();
        let e = move_to_checked(&mut s, 3.0, &policy()).await.unwrap_err();
        assert!(matches!(e, MoveError::Missed { position_mm, .. } if position_mm == 2.99), "{e}");
        assert_eq!(e.kind(), FaultKind::DeviceReported);
    }

    #[tokio::test]
    async fn relative_move_reads_position_checks_travel_and_never_retries() {
        let mut s = stage_with_travel();
        let mut seq = Sequence::new();
        s.expect_position_mm().times(1).in_sequence(&mut seq).returning(|| Ok(11.5));
        // 11.5 + 1.0 is past the 12 mm travel: nothing may be started.
        s.expect_start_move_by_mm().never();
        let e = move_by_checked(&mut s, 1.0, &policy()).await.unwrap_err();
        assert_eq!(e.kind(), FaultKind::Limit);

        let mut s = stage_with_travel();
        let mut seq = Sequence::new();
        s.expect_position_mm().times(1).in_sequence(&mut seq).returning(|| Ok(1.0));
        s.expect_start_move_by_mm()
            .with(eq(-0.25))
            .times(1)
            .in_sequence(&mut seq)
            .returning(|_| Err(Fault(FaultKind::Timeout)));
        s.expect_wait_until_stopped().never();
        let e = move_by_checked(&mut s, -0.25, &policy()).await.unwrap_err();
        assert_eq!(e.kind(), FaultKind::Timeout);

        let mut s = stage_with_travel();
        let mut seq = Sequence::new();
        s.expect_position_mm().times(1).in_sequence(&mut seq).returning(|| Ok(1.0));
        s.expect_start_move_by_mm().times(1).in_sequence(&mut seq).returning(|_| Ok(()));
        s.expect_wait_until_stopped().times(1).in_sequence(&mut seq).returning(|_| Ok(0.75));
        assert_eq!(move_by_checked(&mut s, -0.25, &policy()).await.unwrap(), 0.75);
    }
}
