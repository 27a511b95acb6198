//! The rig's virtual clock. Emulated devices run their dynamics on rig time,
//! which advances `speedup` times faster than wall time, while the drivers that
//! talk to them over real pseudo-terminals keep their real (wall) timeouts.
//! A tokio paused clock cannot do this: with real pty I/O pending it would
//! jump straight to the next timer and fire every timeout at once.

use std::time::{Duration, Instant};

#[derive(Debug, Clone, Copy)]
pub struct VirtualClock {
    origin: Instant,
    speedup: f64,
}

impl VirtualClock {
    /// A clock starting at rig time 0 now. `speedup` = 1 is real time.
    pub fn new(speedup: f64) -> Self {
        let speedup = if speedup.is_finite() && speedup > 0.0 { speedup } else { 1.0 };
        Self { origin: Instant::now(), speedup }
    }

    pub fn realtime() -> Self {
        Self::new(1.0)
    }

    pub fn speedup(&self) -> f64 {
        self.speedup
    }

    /// Rig seconds since the clock started.
    pub fn now_s(&self) -> f64 {
        self.origin.elapsed().as_secs_f64() * self.speedup
    }

    /// Wall time that corresponds to `rig_s` seconds of rig time.
    pub fn wall_for(&self, rig_s: f64) -> Duration {
        // Bounded (a day of wall time) so no rig time, however absurd, panics here.
        Duration::from_secs_f64((rig_s / self.speedup).clamp(0.0, 86_400.0))
    }

    /// Sleep for `rig_s` seconds of rig time.
    pub async fn sleep_rig(&self, rig_s: f64) {
        tokio::time::sleep(self.wall_for(rig_s)).await;
    }
}
