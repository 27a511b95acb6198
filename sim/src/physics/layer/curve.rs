//! The layered contact as a fit evaluates it: the normal states tabulated once
//! over contact radius, read back at any stage approach by monotone cubic
//! interpolation, and the torsion split with the layer's stiffening
//! (docs/physics.md, "Layered contact").

use super::{LayeredNormal, LayeredTorsion, Profile};
use crate::physics::normal::{NormalError, NormalState};
use crate::physics::params::{ContactPair, Layer, ParamError};
use crate::physics::torsion::rod_correction_factor;

/// Contact radii tabulated per model (uniform in a; delta ~ a² near zero).
const GRID: usize = 96;

/// Normal and torsion response of one elastomer layer against one indenter.
#[derive(Debug, Clone)]
pub struct LayeredContact {
    pair: ContactPair,
    torsion: LayeredTorsion,
    /// States at the grid radii, increasing in delta.
    states: Vec<NormalState>,
    /// d(quantity)/d(delta) at the grid points for gamma1, gamma2, force, a.
    slopes: [Vec<f64>; 4],
}

fn quantities(s: &NormalState) -> [f64; 4] {
    [s.gamma1_mm, s.gamma2_mm, s.force_n, s.contact_radius_mm]
}

/// Slopes of a smooth function through (x, y): the derivative of the parabola
/// through each point and its neighbours (one-sided at the ends). Not monotone-
/// preserving on purpose: gamma2 has a maximum inside the range.
fn three_point_slopes(x: &[f64], y: &[f64]) -> Vec<f64> {
    let n = x.len();
    let parabola = |i0: usize, at: usize| {
        let (x0, x1, x2) = (x[i0], x[i0 + 1], x[i0 + 2]);
        let (y0, y1, y2) = (y[i0], y[i0 + 1], y[i0 + 2]);
        let t = x[at];
        y0 * (2.0 * t - x1 - x2) / ((x0 - x1) * (x0 - x2))
            + y1 * (2.0 * t - x0 - x2) / ((x1 - x0) * (x1 - x2))
            + y2 * (2.0 * t - x0 - x1) / ((x2 - x0) * (x2 - x1))
    };
    (0..n).map(|i| parabola(i.saturating_sub(1).min(n - 3), i)).collect()
}

impl LayeredContact {
    /// The contact of `pair` on `layer` for contact radii up to 1.5 indenter radii
    /// (the paper's model lets a soft pair's contact grow past R2 before beta = 0.2).
    pub fn new(pair: &ContactPair, layer: &Layer) -> Result<Self, ParamError> {
        Self::with_profile(pair, layer, Profile::Paraboloid)
    }

    /// As [`Self::new`] with the bodies' shape in the gap chosen.
    pub fn with_profile(pair: &ContactPair, layer: &Layer, profile: Profile) -> Result<Self, ParamError> {
        let a_max = 1.5 * pair.indenter.r_mm;
        let normal = LayeredNormal::with_profile(pair, layer, a_max, profile)?;
        let a_max = normal.max_contact_radius_mm();
        let torsion = LayeredTorsion::new(layer, a_max)?;
        let mut states = vec![NormalState::NONE];
        for k in 1..=GRID {
            let st = normal.at_contact_radius(a_max * k as f64 / GRID as f64);
            // Past the indenter's finite-size turning point the approach falls: stop there.
            let prev = states.last().map_or(0.0, |s| s.delta_mm);
            if st.delta_mm.is_nan() || st.delta_mm <= prev {
                break;
            }
            states.push(st);
        }
        let x: Vec<f64> = states.iter().map(|s| s.delta_mm).collect();
        let slopes = std::array::from_fn(|q| {
            let y: Vec<f64> = states.iter().map(|s| quantities(s)[q]).collect();
            three_point_slopes(&x, &y)
        });
        Ok(Self { pair: *pair, torsion, states, slopes })
    }

    pub fn pair(&self) -> &ContactPair {
        &self.pair
    }

    /// The largest approach tabulated, mm.
    pub fn max_approach_mm(&self) -> f64 {
        self.states.last().map_or(0.0, |s| s.delta_mm)
    }

    /// The state at stage approach `delta_mm` (interpolated; no contact at or below 0).
    pub fn solve(&self, delta_mm: f64) -> Result<NormalState, NormalError> {
        if !delta_mm.is_finite() {
            return Err(NormalError::NotFinite { delta_mm });
        }
        if delta_mm <= 0.0 {
            return Ok(NormalState::NONE);
        }
        let limit = self.max_approach_mm();
        if delta_mm > limit {
            return Err(NormalError::BeyondModel { delta_mm, limit_mm: limit });
        }
        let i = self.states.partition_point(|s| s.delta_mm < delta_mm).clamp(1, self.states.len() - 1) - 1;
        let (s0, s1) = (&self.states[i], &self.states[i + 1]);
        let h = s1.delta_mm - s0.delta_mm;
        let t = (delta_mm - s0.delta_mm) / h;
        let (t2, t3) = (t * t, t * t * t);
        let (h00, h10, h01, h11) = (2.0 * t3 - 3.0 * t2 + 1.0, t3 - 2.0 * t2 + t, -2.0 * t3 + 3.0 * t2, t3 - t2);
        let (q0, q1) = (quantities(s0), quantities(s1));
        let v: [f64; 4] = std::array::from_fn(|q| {
            h00 * q0[q] + h10 * h * self.slopes[q][i] + h01 * q1[q] + h11 * h * self.slopes[q][i + 1]
        });
        Ok(NormalState { delta_mm, gamma1_mm: v[0], gamma2_mm: v[1], force_n: v[2], contact_radius_mm: v[3] })
    }

    /// The elastomer's share theta1 of a total twist `total_rad` at normal state `st`:
    /// the paper's series split (Jäger's torsion, the rod factor c(beta)) with the
    /// elastomer stiffened by the layer at the contact radius.
    pub fn theta1_rad(&self, st: &NormalState, total_rad: f64) -> f64 {
        let beta = st.gamma2_mm / self.pair.indenter.r_mm;
        let c = rod_correction_factor(beta);
        let f = self.torsion.stiffness_factor(st.contact_radius_mm);
        let (g1, g2) = (self.pair.elastomer.shear_mpa(), self.pair.indenter.shear_mpa());
        total_rad / (1.0 + f * c * g1 / g2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::params::Body;
    use crate::physics::{NormalModel, torsion_at};

    #[test]
    fn interpolation_matches_the_exact_solve() {
        let pair = ContactPair { elastomer: Body::new(1.0, 0.48, f64::INFINITY), indenter: Body::new(2.0, 0.4, 5.0) };
        let layer = Layer::bonded(5.0);
        let c = LayeredContact::new(&pair, &layer).unwrap();
        let exact = LayeredNormal::new(&pair, &layer, 7.5).unwrap();
        let top = c.max_approach_mm();
        for k in 1..40 {
            let d = 0.97 * top * k as f64 / 40.0;
            let (x, y) = (c.solve(d).unwrap(), exact.solve(d).unwrap());
            assert!((x.gamma1_mm - y.gamma1_mm).abs() < 2e-7, "delta {d}: {} vs {}", x.gamma1_mm, y.gamma1_mm);
            assert!((x.gamma2_mm - y.gamma2_mm).abs() < 2e-7, "delta {d}");
        }
        assert!(c.solve(top * 1.01).is_err());
    }

    #[test]
    fn thick_layer_torsion_is_the_papers_split() {
        let pair = ContactPair { elastomer: Body::new(0.33, 0.39, 33.0), indenter: Body::new(1.1, 0.39, 5.0) };
        let c = LayeredContact::new(&pair, &Layer::bonded(1e7)).unwrap();
        let hs = NormalModel::new(pair).unwrap().solve_for_gamma2(1.0).unwrap();
        let st = c.solve(hs.delta_mm).unwrap_or_else(|e| panic!("{e}; hs {hs:?}"));
        let paper = torsion_at(&pair, st.gamma2_mm / 5.0, 0.1).theta1_rad;
        assert!((c.theta1_rad(&st, 0.1) / paper - 1.0).abs() < 1e-6);
    }
}
