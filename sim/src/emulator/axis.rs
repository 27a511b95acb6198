//! One motorized axis as the emulators see it: a motor that accelerates,
//! cruises and brakes towards its target under velocity and acceleration
//! limits, hard travel limits with switches, a finite resolution, and optional
//! lost motion (backlash) between the motor and the load it carries.
//!
//! State is advanced lazily to a given rig time, so any number of readers
//! (the protocol emulator, the simulated sensor) see one consistent motion.

/// Integration step of the motion controller, rig seconds.
const STEP_S: f64 = 1e-3;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisConfig {
    /// Maximum velocity, user units per second.
    pub max_velocity: f64,
    /// Acceleration, user units per second squared.
    pub acceleration: f64,
    /// Hard travel limits (the limit switches), user units.
    pub min_position: f64,
    pub max_position: f64,
    /// Smallest commandable increment (one count / microstep), user units.
    pub resolution: f64,
    /// Lost motion on reversal between motor and load, user units (0 = none).
    pub backlash: f64,
    /// Velocity used while homing, user units per second.
    pub home_velocity: f64,
    /// Where the axis sits at power-up, before homing.
    pub power_on_position: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    Idle,
    /// Driving to `target`.
    Moving,
    /// Braking to a standstill, target abandoned.
    Stopping,
    /// Driving to the reverse limit switch at home velocity.
    Homing,
}

#[derive(Debug, Clone)]
pub struct Axis {
    cfg: AxisConfig,
    t_s: f64,
    /// Motor position (what the controller's encoder or step count says).
    motor: f64,
    /// Load position (what the indenter actually does), lagging by the backlash.
    load: f64,
    velocity: f64,
    target: f64,
    mode: Mode,
    homed: bool,
    /// Offset between the controller's position counter and the mechanical position.
    counter_offset: f64,
    /// The lag motor - load is kept inside [lag_hi - backlash, lag_hi].
    lag_hi: f64,
    moves_completed: u64,
    homes_completed: u64,
    /// After homing, the axis moves this far forward of the home switch and
    /// zeroes its counter there (the HOMEPARAMS offset distance; 0 = at the switch).
    home_offset: f64,
    /// The move from the switch to the home offset is under way.
    home_offset_move: bool,
    /// Mechanical position of a home switch the axis passes on its way to
    /// the reverse limit (a continuous-rotation mount's once-a-turn switch);
    /// `None`: homing ends at the reverse limit.
    home_switch: Option<f64>,
}

impl Axis {
    pub fn new(cfg: AxisConfig) -> Self {
        let p = cfg.power_on_position.clamp(cfg.min_position, cfg.max_position);
        Self {
            cfg,
            t_s: 0.0,
            motor: p,
            load: p,
            velocity: 0.0,
            target: p,
            mode: Mode::Idle,
            homed: false,
            counter_offset: 0.0,
            lag_hi: 0.0,
            moves_completed: 0,
            homes_completed: 0,
            home_offset: 0.0,
            home_offset_move: false,
            home_switch: None,
        }
    }

    pub fn config(&self) -> &AxisConfig {
        &self.cfg
    }

    /// Advance the dynamics to rig time `t_s` (earlier times are ignored).
    pub fn advance_to(&mut self, t_s: f64) {
        while self.t_s + STEP_S <= t_s {
            self.step(STEP_S);
        }
        let rest = t_s - self.t_s;
        if rest > 0.0 {
            self.step(rest);
        }
    }

    fn step(&mut self, dt: f64) {
        self.t_s += dt;
        let a = self.cfg.acceleration;
        match self.mode {
            Mode::Idle => {
                self.velocity = 0.0;
                return;
            }
            Mode::Stopping => {
                let dv = a * dt;
                if self.velocity.abs() <= dv {
                    self.motor += 0.5 * self.velocity * (self.velocity.abs() / a);
                    self.velocity = 0.0;
                    self.apply_backlash();
                    self.finish_move();
                    return;
                }
                let v_next = self.velocity - dv * self.velocity.signum();
                self.motor += 0.5 * (self.velocity + v_next) * dt;
                self.velocity = v_next;
            }
            Mode::Moving | Mode::Homing => {
                let (goal, vmax) = if self.mode == Mode::Homing {
                    (self.home_switch.unwrap_or(self.cfg.min_position), self.cfg.home_velocity)
                } else {
                    (self.target, self.cfg.max_velocity)
                };
                let dist = goal - self.motor;
                let dv = a * dt;
                if dist.abs() <= self.cfg.resolution * 0.5 + 1e-12 && self.velocity.abs() <= dv {
                    self.motor = goal;
                    self.velocity = 0.0;
                    self.apply_backlash();
                    if self.mode == Mode::Homing {
                        self.finish_home();
                    } else {
                        self.finish_move();
                    }
                    return;
                }
                let dir = dist.signum();
                let braking = self.velocity * self.velocity / (2.0 * a);
                let toward = self.velocity * dir > 0.0;
                let desired = if toward && braking >= dist.abs() {
                    self.velocity - dv * dir
                } else {
                    (self.velocity + dv * dir).clamp(-vmax, vmax)
                };
                // Never step past the goal: land on it and let the next step finish.
                let next = self.motor + 0.5 * (self.velocity + desired) * dt;
                if (goal - next) * dir < 0.0 {
                    self.motor = goal;
                    self.velocity = 0.0;
                    self.apply_backlash();
                    return;
                }
                self.velocity = desired;
                self.motor = next;
            }
        }
        // Hard limit switches stop the motor where they are.
        if self.motor <= self.cfg.min_position {
            self.motor = self.cfg.min_position;
            if self.mode == Mode::Homing {
                self.velocity = 0.0;
                self.apply_backlash();
                self.finish_home();
                return;
            }
            if self.velocity < 0.0 {
                self.velocity = 0.0;
                self.finish_move();
            }
        } else if self.motor >= self.cfg.max_position {
            self.motor = self.cfg.max_position;
            if self.velocity > 0.0 {
                self.velocity = 0.0;
                self.finish_move();
            }
        }
        self.apply_backlash();
    }

    /// Play operator (Brokate & Sprekels): the load moves only when the lag leaves its band.
    fn apply_backlash(&mut self) {
        let b = self.cfg.backlash;
        if b <= 0.0 {
            self.load = self.motor;
            return;
        }
        let lag = self.motor - self.load;
        if lag > self.lag_hi {
            self.load = self.motor - self.lag_hi;
        } else if lag < self.lag_hi - b {
            self.load = self.motor - (self.lag_hi - b);
        }
    }

    fn finish_move(&mut self) {
        if self.home_offset_move {
            // Arrived at the home offset: homing is complete now.
            self.home_offset_move = false;
            self.mode = Mode::Idle;
            self.homed = true;
            self.homes_completed += 1;
            return;
        }
        if self.mode != Mode::Idle {
            self.moves_completed += 1;
        }
        self.mode = Mode::Idle;
    }

    fn finish_home(&mut self) {
        self.mode = Mode::Idle;
        self.counter_offset = self.motor + self.home_offset;
        if self.home_offset != 0.0 {
            let target = self.counter_offset.clamp(self.cfg.min_position, self.cfg.max_position);
            self.target = target;
            self.mode = Mode::Moving;
            self.home_offset_move = true;
            return;
        }
        self.homed = true;
        self.homes_completed += 1;
    }

    fn quantize(&self, x: f64) -> f64 {
        let r = self.cfg.resolution;
        if r > 0.0 { (x / r).round() * r } else { x }
    }

    /// Command an absolute move to `target` in counter coordinates (relative to home).
    /// Returns `false` (and does not move) when the target lies outside the travel.
    pub fn command_move_to(&mut self, t_s: f64, target: f64) -> bool {
        self.advance_to(t_s);
        let mech = self.quantize(target) + self.counter_offset;
        if !target.is_finite() || mech < self.cfg.min_position - 1e-9 || mech > self.cfg.max_position + 1e-9 {
            return false;
        }
        self.home_offset_move = false;
        self.target = mech;
        self.mode = Mode::Moving;
        true
    }

    pub fn command_home(&mut self, t_s: f64) {
        self.advance_to(t_s);
        self.home_offset_move = false;
        self.homed = false;
        self.mode = Mode::Homing;
    }

    /// Decelerate to a stop (`immediate` = stop dead, as an emergency stop does).
    pub fn command_stop(&mut self, t_s: f64, immediate: bool) {
        self.advance_to(t_s);
        if self.mode == Mode::Idle {
            return;
        }
        // Stopping the move to the home offset abandons the homing.
        self.home_offset_move = false;
        if immediate {
            self.velocity = 0.0;
            self.finish_move();
        } else {
            self.mode = Mode::Stopping;
        }
    }

    /// Change the velocity limit and acceleration (a controller's SET_VELPARAMS).
    /// Non-positive or non-finite values are ignored: the axis keeps moving sanely.
    pub fn set_motion_params(&mut self, max_velocity: f64, acceleration: f64) {
        if max_velocity.is_finite() && max_velocity > 0.0 {
            self.cfg.max_velocity = max_velocity;
        }
        if acceleration.is_finite() && acceleration > 0.0 {
            self.cfg.acceleration = acceleration;
        }
    }

    /// Homing velocity (a controller's SET_HOMEPARAMS), at most the axis'
    /// maximum velocity; non-positive or non-finite values are ignored.
    pub fn set_home_velocity(&mut self, v: f64) {
        if v.is_finite() && v > 0.0 {
            self.cfg.home_velocity = v.min(self.cfg.max_velocity);
        }
    }

    /// Home offset distance: after finding the switch the axis moves this far
    /// forward and zeroes its counter there. A rotation mount homes on a
    /// switch but turns both ways from its zero.
    pub fn set_home_offset(&mut self, offset: f64) {
        if offset.is_finite() {
            self.home_offset = offset;
        }
    }

    /// A home switch at mechanical position `at`: homing drives to it (not
    /// to the reverse limit) and zeroes the counter there. A continuous-
    /// rotation mount passes its switch within one turn; with the travel
    /// standing for +-1 turn around the switch, a power-on position in
    /// [switch, switch + 1 turn) is a physical one.
    pub fn set_home_switch(&mut self, at: f64) {
        if at.is_finite() {
            self.home_switch = Some(at.clamp(self.cfg.min_position, self.cfg.max_position));
        }
    }

    /// Load the position counter with `value` at the current position
    /// (a controller's SET_POSCOUNTER); the mechanics do not move.
    pub fn set_position_counter(&mut self, value: f64) {
        if value.is_finite() {
            self.counter_offset = self.motor - value;
        }
    }

    /// Controller position counter (motor side, relative to home), quantized to the resolution.
    pub fn position(&self) -> f64 {
        self.quantize(self.motor - self.counter_offset)
    }

    /// Mechanical load position (what the indenter does), relative to home, not quantized.
    pub fn load_position(&self) -> f64 {
        self.load - self.counter_offset
    }

    pub fn velocity(&self) -> f64 {
        self.velocity
    }
    pub fn is_moving(&self) -> bool {
        self.mode != Mode::Idle
    }
    pub fn is_homing(&self) -> bool {
        self.mode == Mode::Homing || self.home_offset_move
    }
    pub fn is_homed(&self) -> bool {
        self.homed
    }
    pub fn at_reverse_limit(&self) -> bool {
        self.motor <= self.cfg.min_position + 1e-9
    }
    pub fn at_forward_limit(&self) -> bool {
        self.motor >= self.cfg.max_position - 1e-9
    }
    /// Counts of moves and homes that ran to their end; emulators turn these into "completed" messages.
    pub fn moves_completed(&self) -> u64 {
        self.moves_completed
    }
    pub fn homes_completed(&self) -> u64 {
        self.homes_completed
    }
    /// Soft-limit range in counter coordinates.
    pub fn travel(&self) -> (f64, f64) {
        (self.cfg.min_position - self.counter_offset, self.cfg.max_position - self.counter_offset)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> AxisConfig {
        AxisConfig {
            max_velocity: 2.0,
            acceleration: 4.0,
            min_position: 0.0,
            max_position: 25.0,
            resolution: 1e-4,
            backlash: 0.0,
            home_velocity: 1.0,
            power_on_position: 3.0,
        }
    }

    #[test]
    fn trapezoidal_move_reaches_target_in_expected_time() {
        let mut ax = Axis::new(cfg());
        ax.command_home(0.0);
        ax.advance_to(10.0);
        assert!(ax.is_homed());
        assert!(ax.position().abs() < 1e-9);
        assert!(ax.command_move_to(10.0, 10.0));
        // 10 mm at 2 mm/s with 4 mm/s^2: 0.5 s ramp each end, 4.5 s cruise -> 5.5 s.
        ax.advance_to(15.4);
        assert!(ax.is_moving());
        ax.advance_to(15.6);
        assert!(!ax.is_moving(), "still moving at {}", ax.position());
        assert!((ax.position() - 10.0).abs() < 1e-6);
    }

    #[test]
    fn stop_brakes_within_braking_distance() {
        let mut ax = Axis::new(cfg());
        ax.command_home(0.0);
        ax.advance_to(10.0);
        ax.command_move_to(10.0, 20.0);
        ax.advance_to(12.0);
        let p = ax.position();
        ax.command_stop(12.0, false);
        ax.advance_to(14.0);
        assert!(!ax.is_moving());
        // v = 2 mm/s, a = 4 mm/s^2 -> 0.5 mm.
        assert!((ax.position() - p - 0.5).abs() < 0.01, "{} vs {}", ax.position(), p);
    }

    #[test]
    fn refuses_targets_outside_travel() {
        let mut ax = Axis::new(cfg());
        assert!(!ax.command_move_to(0.0, 26.0));
        assert!(!ax.command_move_to(0.0, f64::NAN));
        assert!(!ax.is_moving());
    }

    #[test]
    fn home_offset_moves_off_the_switch_and_zeroes_there() {
        let mut ax = Axis::new(cfg());
        ax.set_home_offset(10.0);
        ax.command_home(0.0);
        ax.advance_to(3.2);
        // Found the switch after 3 s at 1 mm/s; now on the way to the offset.
        assert!(ax.is_homing() && !ax.is_homed());
        assert_eq!(ax.homes_completed(), 0);
        ax.advance_to(20.0);
        assert!(ax.is_homed() && !ax.is_moving());
        assert_eq!(ax.homes_completed(), 1);
        assert_eq!(ax.moves_completed(), 0);
        assert!(ax.position().abs() < 1e-9);
        assert!((ax.load_position()).abs() < 1e-9);
        assert_eq!(ax.travel(), (-10.0, 15.0));
        assert!(ax.command_move_to(20.0, -5.0));
    }

    #[test]
    fn backlash_makes_load_lag_after_reversal() {
        let mut c = cfg();
        c.backlash = 0.01;
        let mut ax = Axis::new(c);
        ax.command_move_to(0.0, 5.0);
        ax.advance_to(10.0);
        let load_up = ax.load_position();
        assert!((load_up - 5.0).abs() < 1e-9);
        ax.command_move_to(10.0, 4.0);
        ax.advance_to(20.0);
        assert!((ax.load_position() - 4.01).abs() < 1e-9, "{}", ax.load_position());
        assert!((ax.position() - 4.0).abs() < 1e-9);
    }

    /// A continuous-rotation mount powered on anywhere in a turn past its
    /// switch turns back to it at the home velocity (never more than a turn,
    /// 72 s at 5 deg/s) and zeroes its counter there; the seeded power-on
    /// angle is a draw in [0, 360) that differs between seeds.
    #[test]
    fn rotation_mount_finds_its_switch_within_one_turn() {
        use crate::emulator::apt::k10cr1_axis_at;
        for past in [0.0, 1.0, 179.5, 359.0, 725.0] {
            let mut ax = Axis::new(k10cr1_axis_at(past));
            ax.set_home_switch(360.0);
            let turn = past % 360.0;
            assert!((ax.position() - 360.0 - turn).abs() < 1e-4, "{past}: {}", ax.position());
            ax.command_home(0.0);
            // 5 deg/s after a 0.25 s ramp at 20 deg/s^2.
            let expected_s = turn / 5.0 + 0.25;
            ax.advance_to(expected_s - 0.5);
            assert!(turn < 2.0 || !ax.is_homed(), "{past}: homed before the switch");
            ax.advance_to(expected_s + 0.5);
            assert!(ax.is_homed() && !ax.is_moving(), "{past}: not homed after {expected_s} s");
            assert!(ax.position().abs() < 1e-4, "{past}: counter {} at the switch", ax.position());
            assert_eq!(ax.travel(), (-360.0, 360.0));
        }
        let draws: Vec<f64> = (1..=10).map(crate::emulator::served::mount_power_on_deg).collect();
        assert!(draws.iter().all(|d| (0.0..360.0).contains(d)), "{draws:?}");
        let spread = draws.iter().cloned().fold(f64::MIN, f64::max) - draws.iter().cloned().fold(f64::MAX, f64::min);
        assert!(spread > 90.0, "{draws:?}");
    }
}
