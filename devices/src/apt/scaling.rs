//! Unit conversion between the rig's units (mm, degrees) and APT device
//! units (docs/hardware.md A.6). Positions travel as i32 counts; velocity and
//! acceleration parameters use controller-specific factors:
//!
//! * DC servo (KDC101): V = C·T·65536·v, A = C·T²·65536·a with the servo
//!   sample period T = 2048 / 6 MHz.
//! * Stepper family (K10CR1): V = C·53.68·v, A = C·53.68·204.94e-6·a.

/// Z8xx actuator on a KDC101, newer protocol figure (512 counts/rev × 67.49:1, 1 mm lead).
pub const Z8_COUNTS_PER_MM: f64 = 34_554.96;
/// Z8xx, older figure (512 × 67:1) used by the Z8 manual and pylablib.
pub const Z8_COUNTS_PER_MM_OLD: f64 = 34_304.0;
/// K10CR1: 409 600 microsteps per 3 degrees of output.
pub const K10CR1_COUNTS_PER_DEG: f64 = 409_600.0 / 3.0;
/// DC servo sample period, seconds.
pub const SERVO_PERIOD_S: f64 = 2048.0 / 6_000_000.0;

/// Which controller family's velocity/acceleration units apply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum ControllerFamily {
    /// KDC101 / TDC001.
    DcServo,
    /// K10CR1 / KST101 / TST101.
    Stepper,
}

/// A value that cannot be represented in device units.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("{what} = {value} does not fit the i32 device field")]
pub struct OutOfRange {
    pub what: &'static str,
    pub value: f64,
}

/// Conversion for one axis: user unit (mm or degree) <-> device units.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Scale {
    /// C: counts per user unit.
    pub counts_per_unit: f64,
    pub family: ControllerFamily,
    /// Device velocity units per (user unit / s).
    pub velocity_factor: f64,
    /// Device acceleration units per (user unit / s²).
    pub acceleration_factor: f64,
}

fn to_i32(what: &'static str, value: f64) -> Result<i32, OutOfRange> {
    let r = value.round();
    if r.is_finite() && r >= f64::from(i32::MIN) && r <= f64::from(i32::MAX) {
        Ok(r as i32)
    } else {
        Err(OutOfRange { what, value })
    }
}

impl Scale {
    /// A DC servo controller (KDC101) with `c` encoder counts per unit.
    pub fn dc_servo(c: f64) -> Self {
        Self {
            counts_per_unit: c,
            family: ControllerFamily::DcServo,
            velocity_factor: c * SERVO_PERIOD_S * 65_536.0,
            acceleration_factor: c * SERVO_PERIOD_S * SERVO_PERIOD_S * 65_536.0,
        }
    }

    /// A stepper-family controller with `c` microsteps per unit.
    pub fn stepper(c: f64) -> Self {
        Self {
            counts_per_unit: c,
            family: ControllerFamily::Stepper,
            velocity_factor: c * 53.68,
            acceleration_factor: c * 53.68 * 204.94e-6,
        }
    }

    /// KDC101 driving a Z8 actuator with the default (newer) counts per mm.
    pub fn kdc101_z8() -> Self {
        Self::dc_servo(Z8_COUNTS_PER_MM)
    }

    /// K10CR1 with the integer factors the protocol document quotes
    /// (7 329 109 and 1 502, docs/hardware.md A.6); the formula gives
    /// 7 329 109.3 and 1 502.03, and the worked numbers use the integers.
    pub fn k10cr1() -> Self {
        Self {
            counts_per_unit: K10CR1_COUNTS_PER_DEG,
            family: ControllerFamily::Stepper,
            velocity_factor: 7_329_109.0,
            acceleration_factor: 1_502.0,
        }
    }

    pub fn to_counts(&self, x: f64) -> Result<i32, OutOfRange> {
        to_i32("position", x * self.counts_per_unit)
    }
    pub fn from_counts(&self, counts: i32) -> f64 {
        f64::from(counts) / self.counts_per_unit
    }
    pub fn velocity_to_device(&self, v: f64) -> Result<i32, OutOfRange> {
        to_i32("velocity", v * self.velocity_factor)
    }
    pub fn velocity_from_device(&self, v: i32) -> f64 {
        f64::from(v) / self.velocity_factor
    }
    pub fn acceleration_to_device(&self, a: f64) -> Result<i32, OutOfRange> {
        to_i32("acceleration", a * self.acceleration_factor)
    }
    pub fn acceleration_from_device(&self, a: i32) -> f64 {
        f64::from(a) / self.acceleration_factor
    }
    /// Counts per servo period, what the emulator puts in the 16-bit velocity
    /// field of a DC status update (the field's real units are [U], A.6).
    pub fn status_velocity(&self, v: f64) -> i16 {
        let x = (v * self.counts_per_unit * SERVO_PERIOD_S).round();
        x.clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn z8_worked_numbers_from_hardware_md() {
        let s = Scale::kdc101_z8();
        assert_eq!(s.to_counts(1.234).unwrap(), 42_641);
        assert_eq!(s.to_counts(12.0).unwrap(), 414_660);
        assert_eq!(s.to_counts(25.0).unwrap(), 863_874);
        assert_eq!(s.velocity_to_device(2.6).unwrap(), 2_009_752);
        assert_eq!(s.velocity_to_device(2.3).unwrap(), 1_777_857);
        assert_eq!(s.acceleration_to_device(4.0).unwrap(), 1_055);
        // The factors quoted from the protocol PDF.
        assert!((s.velocity_factor - 772_981.369_2).abs() < 0.01);
        assert!((s.acceleration_factor - 263.844_307_2).abs() < 1e-4);
        assert!((s.from_counts(42_641) - 1.234).abs() < 1.0 / Z8_COUNTS_PER_MM);
    }

    #[test]
    fn z8_older_figure_factors() {
        let s = Scale::dc_servo(Z8_COUNTS_PER_MM_OLD);
        assert!((s.velocity_factor - 767_367.49).abs() < 0.05);
        assert!((s.acceleration_factor - 261.93).abs() < 0.01);
    }

    #[test]
    fn k10cr1_worked_numbers() {
        let s = Scale::k10cr1();
        assert_eq!(s.velocity_to_device(10.0).unwrap(), 73_291_090);
        assert_eq!(s.acceleration_to_device(20.0).unwrap(), 30_040);
        assert_eq!(s.to_counts(3.0).unwrap(), 409_600);
        assert_eq!(s.to_counts(360.0).unwrap(), 49_152_000);
        // The formula agrees with the quoted integer factors.
        let f = Scale::stepper(K10CR1_COUNTS_PER_DEG);
        assert!((f.velocity_factor - s.velocity_factor).abs() < 1.0);
        assert!((f.acceleration_factor - s.acceleration_factor).abs() < 0.5);
    }

    #[test]
    fn conversions_invert_and_reject_overflow() {
        let s = Scale::kdc101_z8();
        for v in [0.0, 0.5, 2.3, -1.0] {
            let d = s.velocity_to_device(v).unwrap();
            assert!((s.velocity_from_device(d) - v).abs() < 1e-5);
            let a = s.acceleration_to_device(v).unwrap();
            assert!((s.acceleration_from_device(a) - v).abs() < 0.01);
        }
        // i32 wraps after ~43.7 turns of the K10CR1.
        assert!(Scale::k10cr1().to_counts(44.0 * 360.0).is_err());
        assert!(s.to_counts(f64::NAN).is_err());
    }
}
