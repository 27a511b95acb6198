//! Soft limits. Every move the sequencer commands goes through a
//! [`SafetyGuard`] first; a refused move is never sent to a device.
//!
//! gamma1 cannot be measured before a move, so the guard bounds it: the
//! elastomer cannot deform by more than the extra approach (gamma1 + gamma2 =
//! approach, gamma2 >= 0), so after a move to `target` gamma1 is at most the
//! last measured gamma1 plus the travel past the deeper of the current
//! position and the end of the clear zone.

use std::fmt;

use devices::motion::{Deg, Mm};

use super::script::Script;

/// The soft limits in force, already narrowed to the devices' own travel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SoftLimits {
    pub stage_min_mm: f64,
    pub stage_max_mm: f64,
    /// Positions up to here are known to be clear of the sensor.
    pub clear_until_mm: f64,
    pub max_gamma1_mm: f64,
    pub mount_min_deg: f64,
    pub mount_max_deg: f64,
    pub max_twist_deg: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub enum LimitViolation {
    StageTravel {
        target_mm: f64,
        min_mm: f64,
        max_mm: f64,
    },
    Gamma1 {
        target_mm: f64,
        bound_mm: f64,
        max_mm: f64,
    },
    /// A reading, with the stage standing, past the limit.
    Gamma1Read {
        stage_mm: f64,
        gamma1_mm: f64,
        max_mm: f64,
    },
    MountTravel {
        target_deg: f64,
        min_deg: f64,
        max_deg: f64,
    },
    Twist {
        target_deg: f64,
        twist_deg: f64,
        max_deg: f64,
    },
    NotFinite {
        what: &'static str,
    },
}

impl fmt::Display for LimitViolation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LimitViolation::StageTravel { target_mm, min_mm, max_mm } => {
                write!(f, "stage target {target_mm:.4} mm lies outside the soft travel [{min_mm:.4}, {max_mm:.4}] mm")
            }
            LimitViolation::Gamma1 { target_mm, bound_mm, max_mm } => write!(
                f,
                "stage target {target_mm:.4} mm could deform the elastomer by up to {bound_mm:.4} mm, more than max gamma1 {max_mm:.4} mm"
            ),
            LimitViolation::Gamma1Read { stage_mm, gamma1_mm, max_mm } => write!(
                f,
                "gamma1 read {gamma1_mm:.4} mm at stage {stage_mm:.4} mm, more than max gamma1 {max_mm:.4} mm"
            ),
            LimitViolation::MountTravel { target_deg, min_deg, max_deg } => write!(
                f,
                "mount target {target_deg:.3} deg lies outside the soft travel [{min_deg:.3}, {max_deg:.3}] deg"
            ),
            LimitViolation::Twist { target_deg, twist_deg, max_deg } => write!(
                f,
                "mount target {target_deg:.3} deg is a twist of {twist_deg:.3} deg, more than max twist {max_deg:.3} deg"
            ),
            LimitViolation::NotFinite { what } => write!(f, "{what} is not a finite number"),
        }
    }
}

/// Checks every commanded target against the soft limits.
#[derive(Debug, Clone)]
pub struct SafetyGuard {
    limits: SoftLimits,
    /// Mount angle the twist is measured from.
    twist_zero_deg: f64,
    /// Stage positions where gamma1 was measured, with an upper bound on it
    /// there, sorted by position. gamma1 only grows with the approach and by
    /// no more than it, so each point bounds every deeper position too.
    known: Vec<(f64, f64)>,
}

impl SafetyGuard {
    /// Limits of `script` narrowed to the device travel ranges.
    pub fn new(
        script: &Script,
        (Mm(stage_min_mm), Mm(stage_max_mm)): (Mm, Mm),
        (Deg(mount_min_deg), Deg(mount_max_deg)): (Deg, Deg),
    ) -> Self {
        let l = &script.limits;
        let lo = |a: f64, b: f64| if b.is_finite() { a.max(b) } else { a };
        let hi = |a: f64, b: f64| if b.is_finite() { a.min(b) } else { a };
        let limits = SoftLimits {
            stage_min_mm: lo(l.stage_min_mm, stage_min_mm),
            stage_max_mm: hi(l.stage_max_mm, stage_max_mm),
            clear_until_mm: script.approach.start_mm,
            max_gamma1_mm: l.max_gamma1_mm,
            mount_min_deg: if mount_min_deg.is_finite() { mount_min_deg } else { f64::NEG_INFINITY },
            mount_max_deg: if mount_max_deg.is_finite() { mount_max_deg } else { f64::INFINITY },
            max_twist_deg: l.max_twist_deg,
        };
        Self { limits, twist_zero_deg: 0.0, known: Vec::new() }
    }

    pub fn limits(&self) -> SoftLimits {
        self.limits
    }

    /// Measure twist from this mount angle on (the torsion sweep's start).
    pub fn set_twist_zero(&mut self, deg: f64) {
        self.twist_zero_deg = deg;
    }

    /// Remember that at stage position `mm` gamma1 is at most `gamma1_upper_mm`
    /// (a settled reading plus its uncertainty).
    pub fn note_gamma1(&mut self, mm: f64, gamma1_upper_mm: f64) {
        if !(mm.is_finite() && gamma1_upper_mm.is_finite()) {
            return;
        }
        let i = self.known.partition_point(|p| p.0 < mm);
        match self.known.get_mut(i) {
            Some(p) if p.0 == mm => p.1 = gamma1_upper_mm,
            _ => self.known.insert(i, (mm, gamma1_upper_mm)),
        }
    }

    /// Forget the measured points (the sensor or indenter may have been disturbed).
    pub fn forget_gamma1(&mut self) {
        self.known.clear();
    }

    /// Whether a stage position lies inside the soft travel (used to check
    /// script positions such as the retract point once devices are known).
    pub fn stage_in_travel(&self, mm: f64) -> bool {
        mm.is_finite() && mm >= self.limits.stage_min_mm && mm <= self.limits.stage_max_mm
    }

    /// Upper bound on gamma1 after moving from `current_mm` (where gamma1 is
    /// at most `gamma1_bound_mm`) to `target_mm`: 0 inside the clear zone,
    /// else the bound plus the travel past the deeper of the current position
    /// and the clear zone's end. Unknown values count as the worst case.
    pub fn gamma1_bound(&self, current_mm: f64, gamma1_bound_mm: f64, target_mm: f64) -> f64 {
        let clear = self.limits.clear_until_mm;
        if target_mm <= clear {
            return 0.0;
        }
        if current_mm <= clear {
            // Starting in the clear zone: nothing touches before its end.
            return target_mm - clear;
        }
        let g = if gamma1_bound_mm.is_nan() { f64::INFINITY } else { gamma1_bound_mm.max(0.0) };
        let from = if current_mm.is_finite() { current_mm } else { clear };
        let from_here = g + (target_mm - from).max(0.0);
        let n = self.known.partition_point(|p| p.0 <= target_mm);
        let from_known =
            self.known[..n].iter().map(|&(p, u)| u.max(0.0) + (target_mm - p)).fold(f64::INFINITY, f64::min);
        from_here.min(from_known)
    }

    /// May the stage go from `current_mm` (where gamma1 is at most
    /// `gamma1_bound_mm`) to `target_mm`?
    pub fn check_stage(&self, current_mm: f64, gamma1_bound_mm: f64, target_mm: f64) -> Result<(), LimitViolation> {
        let l = &self.limits;
        if !target_mm.is_finite() {
            return Err(LimitViolation::NotFinite { what: "stage target" });
        }
        if !self.stage_in_travel(target_mm) {
            return Err(LimitViolation::StageTravel { target_mm, min_mm: l.stage_min_mm, max_mm: l.stage_max_mm });
        }
        // A move out never deforms the gel more than standing does: it is
        // always allowed (the depth watch's back-off, when the gel already
        // passed the limit with the stage standing, needs one).
        if current_mm.is_finite() && gamma1_bound_mm.is_finite() && target_mm <= current_mm {
            return Ok(());
        }
        let bound = self.gamma1_bound(current_mm, gamma1_bound_mm, target_mm);
        if bound.is_nan() || bound > l.max_gamma1_mm {
            return Err(LimitViolation::Gamma1 { target_mm, bound_mm: bound, max_mm: l.max_gamma1_mm });
        }
        Ok(())
    }

    pub fn check_mount(&self, target_deg: f64) -> Result<(), LimitViolation> {
        let l = &self.limits;
        if !target_deg.is_finite() {
            return Err(LimitViolation::NotFinite { what: "mount target" });
        }
        if target_deg < l.mount_min_deg || target_deg > l.mount_max_deg {
            return Err(LimitViolation::MountTravel { target_deg, min_deg: l.mount_min_deg, max_deg: l.mount_max_deg });
        }
        let twist = (target_deg - self.twist_zero_deg).abs();
        if twist > l.max_twist_deg + 1e-9 {
            return Err(LimitViolation::Twist { target_deg, twist_deg: twist, max_deg: l.max_twist_deg });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn guard() -> SafetyGuard {
        // Script window 0..24 narrowed by a 0..20 mm device; clear until 10 mm; gamma1 up to 4 mm.
        let mut s = Script::default();
        s.limits.max_gamma1_mm = 4.0;
        SafetyGuard::new(&s, (Mm(0.0), Mm(20.0)), (Deg(-170.0), Deg(170.0)))
    }

    #[test]
    fn stage_window_is_narrowed_to_the_device() {
        let g = guard();
        assert_eq!(g.limits().stage_max_mm, 20.0);
        assert!(g.check_stage(0.0, 0.0, 9.0).is_ok());
        assert!(matches!(g.check_stage(0.0, 0.0, 20.5), Err(LimitViolation::StageTravel { .. })));
        assert!(matches!(g.check_stage(0.0, 0.0, -0.1), Err(LimitViolation::StageTravel { .. })));
        assert!(matches!(g.check_stage(0.0, 0.0, f64::NAN), Err(LimitViolation::NotFinite { .. })));
    }

    #[test]
    fn gamma1_bound_is_measured_plus_extra_approach() {
        let g = guard();
        // From the clear zone, the bound is the travel past its end.
        assert!(g.check_stage(10.0, 0.0, 13.9).is_ok());
        assert!(matches!(g.check_stage(5.0, 0.0, 14.1), Err(LimitViolation::Gamma1 { .. })));
        // Deeper: measured gamma1 plus the step.
        assert!(g.check_stage(13.0, 3.9, 13.09).is_ok());
        let e = g.check_stage(13.0, 3.9, 13.2).unwrap_err();
        assert!(e.to_string().contains("max gamma1"), "{e}");
        // Backing out is always allowed inside the window, whatever gamma1 reads.
        assert!(g.check_stage(13.0, 3.99, 12.0).is_ok());
        assert!(g.check_stage(13.0, f64::NAN, 9.0).is_ok());
        assert!(g.check_stage(13.0, f64::NAN, 12.0).is_err(), "unknown gamma1 deeper than clear is refused");
        // Past the limit already (the gel moved under a standing stage): out
        // is allowed, any way in, even by a micrometre, is not.
        assert!(g.check_stage(13.0, 4.3, 12.9).is_ok());
        assert!(g.check_stage(13.0, 4.3, 13.0).is_ok());
        assert!(matches!(g.check_stage(13.0, 4.3, 13.001), Err(LimitViolation::Gamma1 { .. })));
    }

    #[test]
    fn measured_points_bound_deeper_positions() {
        let mut g = guard();
        // From 10 mm with nothing known, 15 mm could mean 5 mm of gamma1.
        assert!(g.check_stage(11.0, 0.5, 15.0).is_err());
        g.note_gamma1(14.5, 3.0);
        g.note_gamma1(14.9, 3.3);
        g.note_gamma1(14.5, 3.05);
        assert!((g.gamma1_bound(11.0, 0.5, 15.0) - 3.4).abs() < 1e-12);
        assert!(g.check_stage(11.0, 0.5, 15.0).is_ok());
        // A point deeper than the target says nothing about it.
        assert!((g.gamma1_bound(11.0, 0.5, 14.0) - 3.5).abs() < 1e-12);
        assert!(g.check_stage(11.0, 0.5, 15.7).is_err());
        g.forget_gamma1();
        assert!(g.check_stage(11.0, 0.5, 15.0).is_err());
    }

    #[test]
    fn twist_is_measured_from_the_torsion_start() {
        let mut g = guard();
        g.set_twist_zero(20.0);
        assert!(g.check_mount(30.0).is_ok());
        assert!(matches!(g.check_mount(30.5), Err(LimitViolation::Twist { .. })));
        assert!(matches!(g.check_mount(9.0), Err(LimitViolation::Twist { .. })));
        assert!(matches!(g.check_mount(171.0), Err(LimitViolation::MountTravel { .. })));
    }
}
