//! "Arrived and standing still", checked once for every driver that needs it.
//!
//! A driver that takes the end of a move from a completion message may be
//! handed one that belongs to an earlier move or to a stop (APT units answer
//! a stop even when idle, and a MOVE_COMPLETED can arrive after a status poll
//! already saw the previous move end). A caller that believed it would read
//! the sensor before the axis had even started, and record the old depth at
//! the new position. [`confirm`] closes that gap from inside the driver's
//! `wait_until_stopped`: after the driver's own end of move, the position is
//! checked against the target, and status polls go on until the axis is
//! there, stands still elsewhere for [`STALL_GRACE`], or the time is up.

use std::time::Duration;

use tokio::time::Instant;

use super::{Axis, Unit};

/// Distance from the target within which a move counts as arrived, in the
/// axis' unit (tens of encoder counts or microsteps).
pub const ARRIVED: f64 = 1e-3;
/// An axis standing still away from its target this long (wall time) has
/// stopped short (a limit, a stop): its position is returned as it is.
pub const STALL_GRACE: Duration = Duration::from_millis(300);
/// Status poll period while checking arrival.
pub const ARRIVAL_POLL: Duration = Duration::from_millis(2);
/// Longest wait for a stopped axis to come to rest (a Z8 decelerates from
/// full speed in well under a second), for drivers whose stop command
/// returns before the motion has ended.
pub const STOP_WAIT: Duration = Duration::from_secs(5);

/// `now + d`, saturating at a year ahead instead of overflowing on huge timeouts.
pub fn deadline_after(d: Duration) -> Instant {
    let now = Instant::now();
    now.checked_add(d).unwrap_or_else(|| now + Duration::from_secs(365 * 24 * 3600))
}

/// The driver's own wait said the axis stopped at `reached`; make sure it
/// stopped at `target`. Returns where the axis really stands: the target
/// (within [`ARRIVED`]), or wherever it has stood still for [`STALL_GRACE`],
/// or its last position when `deadline` passes.
pub async fn confirm<A: Axis + ?Sized>(
    axis: &mut A,
    target: A::Unit,
    reached: A::Unit,
    deadline: Instant,
) -> Result<A::Unit, A::Error> {
    let target = target.value();
    let mut position = reached.value();
    let mut still_since: Option<Instant> = None;
    while (position - target).abs() > ARRIVED {
        let now = Instant::now();
        if now >= deadline || still_since.is_some_and(|t| now.duration_since(t) >= STALL_GRACE) {
            break;
        }
        tokio::time::sleep(ARRIVAL_POLL).await;
        let s = axis.status().await?;
        position = s.position;
        if s.moving {
            still_since = None;
        } else if still_since.is_none() {
            still_since = Some(Instant::now());
        }
    }
    Ok(A::Unit::new(position))
}

#[cfg(test)]
mod tests {
    //! On tokio's paused clock: the grace and the deadline pass without real waiting.
    use super::*;
    use crate::motion::{AxisStatus, DeviceFault, DeviceInfo, FaultKind, Identify, Mm};
    use async_trait::async_trait;
    use mockall::{Sequence, mock};

    #[derive(Debug, Clone, PartialEq, thiserror::Error)]
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
        impl Identify for Stage {
            type Error = Fault;
            async fn identify(&mut self) -> Result<DeviceInfo, Fault>;
        }
        #[async_trait]
        impl Axis for Stage {
            type Unit = Mm;
            fn travel(&self) -> (Mm, Mm);
            async fn home(&mut self, timeout: Duration) -> Result<(), Fault>;
            async fn start_move_to(&mut self, target: Mm) -> Result<(), Fault>;
            async fn start_move_by(&mut self, delta: Mm) -> Result<(), Fault>;
            async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<Mm, Fault>;
            async fn stop(&mut self) -> Result<(), Fault>;
            async fn position(&mut self) -> Result<Mm, Fault>;
            async fn status(&mut self) -> Result<AxisStatus, Fault>;
        }
    }

    fn at(position: f64, moving: bool) -> AxisStatus {
        AxisStatus { position, moving, ..AxisStatus::default() }
    }

    fn far() -> Instant {
        deadline_after(Duration::from_secs(60))
    }

    #[tokio::test(start_paused = true)]
    async fn an_arrived_axis_is_not_asked_again() {
        let mut s = MockStage::new();
        s.expect_status().never();
        let p = confirm(&mut s, Mm(2.0), Mm(2.0 + 0.9 * ARRIVED), far()).await.unwrap();
        assert_eq!(p, Mm(2.0 + 0.9 * ARRIVED));
    }

    #[tokio::test(start_paused = true)]
    async fn a_late_end_of_move_is_followed_until_the_axis_is_there() {
        // The driver's wait ended at the old position (5 mm) on a stale
        // message; the axis then moves to 1 mm and stops there.
        let mut s = MockStage::new();
        let mut seq = Sequence::new();
        for st in [at(5.0, false), at(4.0, true), at(2.0, true), at(1.0, false)] {
            s.expect_status().times(1).in_sequence(&mut seq).returning(move || Ok(st));
        }
        let t0 = Instant::now();
        assert_eq!(confirm(&mut s, Mm(1.0), Mm(5.0), far()).await.unwrap(), Mm(1.0));
        assert!(t0.elapsed() < STALL_GRACE, "{:?}", t0.elapsed());
    }

    #[tokio::test(start_paused = true)]
    async fn an_axis_standing_short_of_the_target_is_believed_after_the_grace() {
        let mut s = MockStage::new();
        s.expect_status().returning(|| Ok(at(3.0, false)));
        let t0 = Instant::now();
        assert_eq!(confirm(&mut s, Mm(10.0), Mm(3.0), far()).await.unwrap(), Mm(3.0));
        let waited = t0.elapsed();
        assert!(waited >= STALL_GRACE && waited < STALL_GRACE + 10 * ARRIVAL_POLL, "{waited:?}");
    }

    #[tokio::test(start_paused = true)]
    async fn the_deadline_ends_the_check_with_the_last_position() {
        let mut s = MockStage::new();
        s.expect_status().returning(|| Ok(at(7.5, true)));
        let deadline = deadline_after(Duration::from_millis(50));
        assert_eq!(confirm(&mut s, Mm(10.0), Mm(3.0), deadline).await.unwrap(), Mm(7.5));
        assert!(Instant::now() >= deadline);
    }

    #[tokio::test(start_paused = true)]
    async fn a_failing_status_is_the_error() {
        let mut s = MockStage::new();
        s.expect_status().times(1).returning(|| Err(Fault(FaultKind::Disconnected)));
        let e = confirm(&mut s, Mm(10.0), Mm(3.0), far()).await.unwrap_err();
        assert_eq!(e, Fault(FaultKind::Disconnected));
    }
}
