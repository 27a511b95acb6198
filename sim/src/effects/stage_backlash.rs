//! `stage_backlash`: lost motion of the stage on reversal (docs/physics.md 2.5).
//!
//! Model: the play operator (Brokate & Sprekels) between commanded position x
//! and true position y, y in [x, x + b]: loading pushes y = x, retraction leaves
//! y until x + b < y. "Engaged" means the slack was taken up in the loading
//! direction before the sweep; otherwise the first b of loading is lost.
//!
//! Shows as a constant shift of the unloading branch (gamma1 above the model)
//! with a dead zone at the turn; the torsion phase is unaffected.

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "stage_backlash",
    model: "play operator of width b between commanded and true stage position",
    params: &[ParamInfo { name: "b_mm", unit: "mm", min: 0.0, max: 0.2, typical: "0.001-0.020 mm" }],
    signature: "unloading branch shifted by a constant (gamma1 above model), dead zone at the turn; load branch and torsion unaffected",
    identifiability: Identifiability::Good,
    sentence: "the stage loses motion when it reverses, so the unloading branch is pressed deeper than commanded",
    explanation: "A lead screw or micrometer has a little play. When the stage turns round at the bottom of the press, the \
first few micrometres of retraction only take up that play and the indenter does not move. The whole unloading branch \
is therefore pressed slightly deeper than the stage says, by the same amount everywhere, while the loading branch is \
fine. Fitting the play width removes the mismatch between the two branches.",
    separate_by: None,
};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// Play width, mm.
    pub b_mm: f64,
    /// Slack taken up in the loading direction before the sweep.
    #[serde(default = "engaged_default")]
    pub engaged: bool,
}

fn engaged_default() -> bool {
    true
}

impl Params {
    pub fn validate(&self) -> Result<(), EffectError> {
        check(&INFO, 0, self.b_mm)
    }
}

/// Play operator state: output position of a drive with lost motion `b`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Play {
    b: f64,
    y: Option<f64>,
    engaged: bool,
    origin: f64,
}

impl Play {
    pub fn new(b: f64, engaged: bool) -> Self {
        Self { b: b.max(0.0), y: None, engaged, origin: 0.0 }
    }
    /// True position for the commanded position `x`, relative to where the drive
    /// started (the first command defines the zero of both).
    pub fn step(&mut self, x: f64) -> f64 {
        match self.y {
            None => {
                // Not engaged: the slack lies on the loading side, the first b of travel is lost.
                let y = if self.engaged { x } else { x + self.b };
                self.origin = y - x;
                self.y = Some(y);
                x
            }
            Some(y) => {
                let y = y.max(x).min(x + self.b);
                self.y = Some(y);
                y - self.origin
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn play_loses_motion_on_reversal_only() {
        let mut p = Play::new(0.01, true);
        assert_eq!(p.step(0.0), 0.0);
        assert_eq!(p.step(0.05), 0.05);
        // Reversal: the first 10 um of retraction do not move the output.
        assert!((p.step(0.045) - 0.05).abs() < 1e-15);
        assert!((p.step(0.03) - 0.04).abs() < 1e-15);
        // Forward again: the slack is taken up before the output moves.
        assert!((p.step(0.035) - 0.04).abs() < 1e-15);
        assert!((p.step(0.06) - 0.06).abs() < 1e-15);
        let mut q = Play::new(0.01, false);
        assert_eq!(q.step(0.0), 0.0);
        assert!((q.step(0.005) - 0.0).abs() < 1e-15);
        assert!((q.step(0.05) - 0.04).abs() < 1e-15);
    }
}
