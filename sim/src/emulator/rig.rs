//! The emulated rig as one mechanical system: the stage axis and the rotation
//! axis on one virtual clock. The protocol emulators command the axes; the
//! simulated sensor reads where the indenter really is (load side, after
//! backlash) at the rig time of each frame.

use std::sync::{Arc, Mutex, MutexGuard};

use super::axis::{Axis, AxisConfig};
use crate::clock::VirtualClock;

/// Where the indenter is, in the rig's mechanical frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigPose {
    /// Rig time, s.
    pub t_s: f64,
    /// Stage load position relative to the stage's home, mm.
    pub stage_mm: f64,
    /// Mount load angle relative to its home, degrees.
    pub rot_deg: f64,
}

/// Shared handle to the emulated rig; cheap to clone.
#[derive(Debug, Clone)]
pub struct Rig {
    clock: VirtualClock,
    stage: Arc<Mutex<Axis>>,
    rotation: Arc<Mutex<Axis>>,
}

fn lock(axis: &Mutex<Axis>) -> MutexGuard<'_, Axis> {
    // A panic elsewhere must not take the whole emulated rig down with it.
    axis.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl Rig {
    pub fn new(clock: VirtualClock, stage: AxisConfig, rotation: AxisConfig) -> Self {
        Self {
            clock,
            stage: Arc::new(Mutex::new(Axis::new(stage))),
            rotation: Arc::new(Mutex::new(Axis::new(rotation))),
        }
    }

    pub fn clock(&self) -> VirtualClock {
        self.clock
    }

    /// Run `f` on the stage axis, advanced to the current rig time.
    pub fn with_stage<R>(&self, f: impl FnOnce(&mut Axis, f64) -> R) -> R {
        let t = self.clock.now_s();
        let mut ax = lock(&self.stage);
        ax.advance_to(t);
        f(&mut ax, t)
    }

    /// Run `f` on the rotation axis, advanced to the current rig time.
    pub fn with_rotation<R>(&self, f: impl FnOnce(&mut Axis, f64) -> R) -> R {
        let t = self.clock.now_s();
        let mut ax = lock(&self.rotation);
        ax.advance_to(t);
        f(&mut ax, t)
    }

    /// The indenter's pose now.
    pub fn pose(&self) -> RigPose {
        let t_s = self.clock.now_s();
        let stage_mm = {
            let mut ax = lock(&self.stage);
            ax.advance_to(t_s);
            ax.load_position()
        };
        let rot_deg = {
            let mut ax = lock(&self.rotation);
            ax.advance_to(t_s);
            ax.load_position()
        };
        RigPose { t_s, stage_mm, rot_deg }
    }
}
