//! `partial_slip`: Coulomb slip annulus under twist (docs/physics.md 2.7).
//!
//! Model: Hertz pressure p0 sqrt(1 - r^2/a^2), friction mu. Jäger's superposition
//! of rigid disc rotations with the density phi'(s) = mu p0 E(1 - s^2/a^2) / (2 Ge s)
//! gives, with kappa = c/a the stick radius,
//! M = (8/3) mu p0 a^3 int_kappa^1 u^2 E(1-u^2) du and
//! theta_rel = mu p0/(2 Ge) int_kappa^1 E(1-u^2)/u du. The sensor fits one rigid
//! rotation to the elastomer's share of the surface field over the contact disc,
//! theta1 = 4 int u1 r^2 dr / a^4. The mount supplies theta_rel + C_rod M. On
//! reversal every quantity follows Masing's rule q = q_r + 2 q_virgin((M - M_r)/2),
//! with Madelung memory when a loop closes.
//!
//! The dimensionless integrals do not depend on any parameter: they are tabulated
//! once over kappa. The torsion depth state (F, a) is frozen when the twist starts
//! at a new stage position.

use std::f64::consts::PI;
use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "partial_slip",
    model: "Coulomb friction mu with Hertz pressure: slip annulus (Jäger/Lubkin), marker-fit theta1, Masing reversal",
    params: &[ParamInfo {
        name: "mu",
        unit: "",
        min: 0.05,
        max: 100.0,
        typical: "0.3-2 (silicone on silicone usually > 1)",
    }],
    signature: "torsion: theta1 linear at small twist then concave; the return starts with the stick slope and runs below the outgoing branch in theta1 (above it in theta2), a Masing loop ending at a negative theta1; H3 biased up; normal sweep unaffected",
    identifiability: Identifiability::Good,
    sentence: "the indenter starts to slip at the edge of the contact under twist, so the sensor's rotation stops tracking the mount",
    explanation: "The paper assumes the indenter grips the gel perfectly while it twists. With real friction the outer ring of \
the contact, where the pressure is lowest, starts to slide as soon as the twist begins, and the sliding ring grows \
inward as the twist increases. The rotation the sensor sees then lags behind a straight line, and on the way back it \
follows a different curve, forming a loop. A straight-line fit of the torsion sweep reads that as a different \
stiffness.",
    separate_by: None,
};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// Coulomb friction coefficient.
    pub mu: f64,
}

impl Params {
    pub fn validate(&self) -> Result<(), EffectError> {
        check(&INFO, 0, self.mu)
    }
}

/// Complete elliptic integral of the second kind, parameter m (E(0) = pi/2, E(1) = 1), by the AGM.
pub fn elliptic_e(m: f64) -> f64 {
    if m >= 1.0 {
        return 1.0;
    }
    let mut a = 1.0;
    let mut b = (1.0 - m).sqrt();
    let mut c2sum = 0.5 * m; // 2^(n-1) c_n^2 with c_0^2 = m
    let mut pow = 0.5;
    for _ in 0..40 {
        let an = 0.5 * (a + b);
        let bn = (a * b).sqrt();
        let cn = 0.5 * (a - b);
        pow *= 2.0;
        c2sum += pow * cn * cn;
        a = an;
        b = bn;
        if cn.abs() < 1e-16 {
            break;
        }
    }
    PI / (2.0 * a) * (1.0 - c2sum)
}

/// Marker-fit rotation of a unit rigid disc rotation of radius sigma (in units of a):
/// 4/a^4 int_0^a u(r) r^2 dr for u = r inside, (2/pi)[r asin(s/r) - s sqrt(1 - s^2/r^2)] outside.
fn disc_marker_rotation(sigma: f64) -> f64 {
    if sigma >= 1.0 {
        return 1.0;
    }
    let n = 200;
    let h = (1.0 - sigma) / n as f64;
    let g = |rho: f64| {
        let x = (sigma / rho).min(1.0);
        rho.powi(3) * x.asin() - sigma * rho * rho * (1.0 - x * x).max(0.0).sqrt()
    };
    // Simpson's rule.
    let mut s = g(sigma) + g(1.0);
    for i in 1..n {
        let rho = sigma + i as f64 * h;
        s += if i % 2 == 1 { 4.0 } else { 2.0 } * g(rho);
    }
    sigma.powi(4) + 8.0 / PI * s * h / 3.0
}

/// Dimensionless virgin curves on a kappa grid from 1 (no slip) down to KMIN.
struct Tables {
    /// (8/3) int_kappa^1 u^2 E(1-u^2) du.
    torque: Vec<f64>,
    /// int_kappa^1 E(1-u^2)/u du.
    rel: Vec<f64>,
    /// int_kappa^1 E(1-u^2) D(u)/u du.
    marker: Vec<f64>,
}

const KMIN: f64 = 1e-3;
const N: usize = 1500;

fn tables() -> &'static Tables {
    static T: OnceLock<Tables> = OnceLock::new();
    T.get_or_init(|| {
        // Geometric grid: fine near kappa = 0 where 1/u grows, still < 0.5 % steps near 1.
        let kappa: Vec<f64> = (0..=N).map(|j| KMIN.powf(j as f64 / N as f64)).collect();
        let e: Vec<f64> = kappa.iter().map(|&u| elliptic_e(1.0 - u * u)).collect();
        let d: Vec<f64> = kappa.iter().map(|&u| disc_marker_rotation(u)).collect();
        let (mut torque, mut rel, mut marker) = (vec![0.0; N + 1], vec![0.0; N + 1], vec![0.0; N + 1]);
        for j in 1..=N {
            let (u0, u1) = (kappa[j - 1], kappa[j]);
            let h = u0 - u1;
            torque[j] = torque[j - 1] + 8.0 / 3.0 * 0.5 * h * (u0 * u0 * e[j - 1] + u1 * u1 * e[j]);
            // int E/u du over one cell, with E linear and the log done exactly.
            let ln = (u0 / u1).ln();
            let em = 0.5 * (e[j - 1] + e[j]);
            rel[j] = rel[j - 1] + em * ln;
            marker[j] = marker[j - 1] + 0.5 * (e[j - 1] * d[j - 1] + e[j] * d[j]) * ln;
        }
        Tables { torque, rel, marker }
    })
}

/// Gross-slip torque fraction check: (8/3) int_0^1 u^2 E du = pi^2/8 (so M_max = 3 pi mu F a / 16).
pub fn torque_integral_at_gross_slip() -> f64 {
    let t = tables();
    t.torque[N]
}

/// The frozen torsion state of one hold, with the Masing branch stack.
#[derive(Debug, Clone)]
pub struct SlipState {
    /// mu p0 a^3, N mm.
    torque_scale: f64,
    /// mu p0 / (2 Ge), rad.
    rel_scale: f64,
    /// Elastomer share of the relative rotation, C1/(C1 + C2).
    share: f64,
    /// Rod compliance, rad / (N mm).
    c_rod: f64,
    /// Branches: (origin torque, origin mount angle, origin theta1, factor 1 or 2).
    stack: Vec<(f64, f64, f64, f64)>,
    last_total: f64,
    last: (f64, f64),
    dir: f64,
}

impl SlipState {
    /// `force_n`, `a_t` contact radius, contact compliances c1, c2 and rod compliance (rad per N mm).
    pub fn new(mu: f64, force_n: f64, a_t: f64, c1: f64, c2: f64, c_rod: f64) -> Self {
        let p0 = 3.0 * force_n.max(0.0) / (2.0 * PI * a_t * a_t);
        // 3/(16 Ge a^3) = c1 + c2 defines the effective shear modulus of the pair.
        let ge = 3.0 / (16.0 * a_t.powi(3) * (c1 + c2));
        Self {
            torque_scale: mu * p0 * a_t.powi(3),
            rel_scale: mu * p0 / (2.0 * ge),
            share: c1 / (c1 + c2),
            c_rod,
            stack: vec![(0.0, 0.0, 0.0, 1.0)],
            last_total: 0.0,
            last: (0.0, 0.0),
            dir: 0.0,
        }
    }

    /// Virgin curve at mount-angle magnitude x (rad): (torque, theta1). None past gross slip.
    fn virgin(&self, x: f64) -> Option<(f64, f64)> {
        if x <= 0.0 {
            return Some((0.0, 0.0));
        }
        let t = tables();
        let total = |j: usize| self.rel_scale * t.rel[j] + self.c_rod * self.torque_scale * t.torque[j];
        if x > total(N) {
            return None;
        }
        let (mut lo, mut hi) = (0usize, N);
        while hi - lo > 1 {
            let mid = (lo + hi) / 2;
            if total(mid) < x { lo = mid } else { hi = mid }
        }
        let (y0, y1) = (total(lo), total(hi));
        let f = if y1 > y0 { (x - y0) / (y1 - y0) } else { 0.0 };
        let lerp = |v: &[f64]| v[lo] + f * (v[hi] - v[lo]);
        Some((self.torque_scale * lerp(&t.torque), self.share * self.rel_scale * lerp(&t.marker)))
    }

    /// theta1 (rad) for the mount angle `total` (rad), following the branch history.
    pub fn theta1(&mut self, total: f64) -> Option<f64> {
        let d = total - self.last_total;
        if d == 0.0 {
            return Some(self.last.1);
        }
        let s = d.signum();
        if self.dir != 0.0 && s != self.dir {
            // Reversal: a new Masing branch from the current state.
            self.stack.push((self.last.0, self.last_total, self.last.1, 2.0));
        }
        self.dir = s;
        // Madelung: a branch that reaches the point where its loop closes is forgotten.
        while self.stack.len() >= 2 {
            let k = self.stack.len() - 1;
            let (_, tt_o, _, _) = self.stack[k];
            let (_, tt_p, _, f_p) = self.stack[k - 1];
            let close = if f_p == 1.0 { 2.0 * (tt_o - tt_p).abs() } else { (tt_o - tt_p).abs() };
            if (total - tt_o).abs() >= close && (total - tt_o).signum() == (tt_p - tt_o).signum() {
                self.stack.pop();
                if f_p != 1.0 {
                    self.stack.pop();
                }
            } else {
                break;
            }
        }
        let &(m_o, tt_o, th_o, f) = self.stack.last()?;
        let dx = total - tt_o;
        let (m, th) = self.virgin(dx.abs() / f)?;
        let m = m_o + dx.signum() * f * m;
        let th = th_o + dx.signum() * f * th;
        self.last_total = total;
        self.last = (m, th);
        Some(th)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn elliptic_and_gross_slip_torque() {
        assert!((elliptic_e(0.0) - PI / 2.0).abs() < 1e-14);
        assert!((elliptic_e(0.5) - 1.350_643_881_047_675_5).abs() < 1e-12);
        assert!((elliptic_e(1.0) - 1.0).abs() < 1e-14);
        // Lubkin: M_max = 3 pi mu F a / 16 <=> (8/3) int_0^1 u^2 E(1-u^2) du = pi^2/8.
        assert!(
            (torque_integral_at_gross_slip() / (PI * PI / 8.0) - 1.0).abs() < 2e-3,
            "{}",
            torque_integral_at_gross_slip()
        );
        assert!((disc_marker_rotation(1.0) - 1.0).abs() < 1e-12);
        assert!(disc_marker_rotation(0.5) > 0.0625 && disc_marker_rotation(0.5) < 1.0);
    }

    #[test]
    fn small_twist_is_stick_and_large_twist_lags_with_masing_loop() {
        let (c1, c2, crod) = (0.01, 0.004, 0.003);
        let mut s = SlipState::new(1.0, 6.0, 3.6, c1, c2, crod);
        let stick = c1 / (c1 + c2 + crod);
        let small = s.theta1(1e-5).unwrap();
        assert!((small / 1e-5 / stick - 1.0).abs() < 0.01, "{} vs {stick}", small / 1e-5);
        let mut out = Vec::new();
        for i in 1..=20 {
            out.push(s.theta1(i as f64 * 0.005).unwrap());
        }
        // Concave: the secant slope falls.
        assert!(out[19] / 0.1 < stick * 0.99);
        // Masing: the return from the turn (0.1 rad) is the virgin curve doubled in
        // both axes, q = q_r - 2 q_virgin(d/2). It starts with the stick slope,
        // so in theta1 against mount angle it runs below the (concave) outgoing
        // branch; the indenter twist theta2 = mount - theta1 runs above it, which
        // is what biases the through-origin H3 upward.
        let mut virgin = SlipState::new(1.0, 6.0, 3.6, c1, c2, crod);
        let v_half = virgin.theta1(0.025).unwrap();
        let back = s.theta1(0.05).unwrap();
        assert!((back - (out[19] - 2.0 * v_half)).abs() < 1e-9 * out[19], "{back} vs Masing");
        assert!(back < out[9], "{back} vs {}", out[9]);
        assert!(0.05 - back > 0.05 - out[9]);
        // Back at zero twist the loop leaves a residual rotation.
        let zero = s.theta1(0.0).unwrap();
        assert!(zero < -1e-6, "{zero}");
        // Out again past the turn: Madelung memory rejoins the virgin curve.
        s.theta1(0.05).unwrap();
        let again = s.theta1(0.1).unwrap();
        assert!((again - out[19]).abs() < 1e-9 * out[19], "{again} vs {}", out[19]);
    }
}
