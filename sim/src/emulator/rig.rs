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

/// One entry of the rig's motion log: the pose and what each axis was doing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionSample {
    pub pose: RigPose,
    pub stage_homed: bool,
    pub stage_moving: bool,
    pub rot_moving: bool,
    pub rot_homing: bool,
}

/// Shared handle to the emulated rig; cheap to clone.
#[derive(Debug, Clone)]
pub struct Rig {
    clock: VirtualClock,
    stage: Arc<Mutex<Axis>>,
    rotation: Arc<Mutex<Axis>>,
    /// Every pose taken (the simulated sensor takes one a frame), once
    /// [`Rig::log_motion`] switched it on.
    motion_log: Arc<Mutex<Option<Vec<MotionSample>>>>,
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
            motion_log: Arc::new(Mutex::new(None)),
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
        let (stage_mm, stage_homed, stage_moving) = {
            let mut ax = lock(&self.stage);
            ax.advance_to(t_s);
            (ax.load_position(), ax.is_homed(), ax.is_moving())
        };
        let (rot_deg, rot_moving, rot_homing) = {
            let mut ax = lock(&self.rotation);
            ax.advance_to(t_s);
            (ax.load_position(), ax.is_moving(), ax.is_homing())
        };
        let pose = RigPose { t_s, stage_mm, rot_deg };
        let mut log = self.motion_log.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(log) = log.as_mut() {
            log.push(MotionSample { pose, stage_homed, stage_moving, rot_moving, rot_homing });
        }
        pose
    }

    /// Start (or stop) logging every pose taken, with what the axes were
    /// doing: a test's view of the rig's motion (the sensor takes a pose
    /// every frame, so the log holds one entry a frame at least).
    pub fn log_motion(&self, on: bool) {
        let mut log = self.motion_log.lock().unwrap_or_else(|p| p.into_inner());
        *log = on.then(|| log.take().unwrap_or_default());
    }

    /// The motion logged so far.
    pub fn motion_log(&self) -> Vec<MotionSample> {
        self.motion_log.lock().unwrap_or_else(|p| p.into_inner()).clone().unwrap_or_default()
    }
}
