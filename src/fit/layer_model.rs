//! The declared layer's forward model in the fit (docs/physics.md,
//! "Finite-element reference" and "Large strain"): the project's FE reference
//! of a hemisphere on a bonded gel, with Coulomb friction in both sweeps, its
//! fast frictionless form plus a deferred friction correction, and at large
//! strain the tabulated ratios of the neo-Hookean reference (its press, its stuck
//! twist and its slip) on the
//! frictionless press (friction then acts in the twist only).

use std::collections::HashMap;
use std::collections::hash_map::Entry;

use rayon::prelude::*;
use sim::physics::Layer;
use sim::recording::{Phase, Recording};

use super::FitError;
use super::full::{ModelParams, Prediction, fe_layer};

/// Per-sample (gamma1 mm, theta1 deg) to add to the FE model's frictionless
/// normal state to stand for the frictional one (a deferred correction: see
/// [`friction_correction`]), linear in the parameters about where it was taken.
pub(super) struct Correction {
    /// E1, nu1, z0 and friction where it was taken.
    at: Vec<f64>,
    base: Vec<(f64, f64)>,
    /// Its derivative in each of those parameters, per sample.
    slope: Vec<Vec<(f64, f64)>>,
}

impl Correction {
    /// The correction at `p`, per sample.
    pub(super) fn at(&self, p: &ModelParams) -> impl Iterator<Item = (f64, f64)> + '_ {
        let mut moved: Vec<f64> = physical(p).iter().zip(&self.at).map(|(v, a)| v - a).collect();
        if let (Some(m), Some(&a)) = (moved.get_mut(3), self.at.get(3)) {
            *m = friction_move(a + *m, a);
        }
        self.base.iter().enumerate().map(move |(i, &(g, t))| {
            self.slope.iter().zip(&moved).fold((g, t), |(g, t), (d, m)| (g + d[i].0 * m, t + d[i].1 * m))
        })
    }
}

/// How far the friction `mu` lies from `at` (where a correction was taken)
/// for the correction's slope: itself below, `at` ln(mu / at) above. Friction
/// acts less and less as it grows (past the value at which the whole contact
/// sticks, not at all), so above, the correction follows its slope in
/// ln(friction); a slope per unit friction followed far up (the linear
/// model's fit of the neo-Hookean tableI_2 took the friction from 8.9 to
/// 10⁴) read a correction thousands of times too large. Below, it is
/// followed as it is: towards zero friction the correction goes to zero, not
/// to minus infinity as it would in ln(friction). The two meet with the same
/// slope at `at`.
fn friction_move(mu: f64, at: f64) -> f64 {
    if mu > at { at * (mu / at).ln() } else { mu - at }
}

/// E1, nu1, z0 and (when fitted) the friction coefficient.
fn physical(p: &ModelParams) -> Vec<f64> {
    let mut v = vec![p.e1_mpa, p.nu1, p.contact_offset_mm];
    v.extend(p.contact_friction);
    v
}

/// The normal contact in the FE model: followed with Coulomb friction along the
/// approach (the model itself), or frictionless with each depth solved on its
/// own (its fast form, several times cheaper; see [`friction_correction`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum NormalContact {
    Frictional,
    Frictionless,
}

/// The layered contact from the project's own FE reference (docs/physics.md,
/// "Finite-element reference"): a hemisphere held at its flat face on a bonded gel,
/// with Coulomb friction between them in both sweeps (one coefficient).
pub(super) fn predict_fe(
    rec: &Recording,
    p: &ModelParams,
    layer: Layer,
    normal: NormalContact,
) -> Result<Vec<Prediction>, FitError> {
    let ind = rec.meta.indenter;
    let fw = crate::layer::forward(&layer, ind.e_mpa, ind.nu, ind.r_mm)?;
    if !(p.e1_mpa.is_finite() && p.e1_mpa > 0.0 && (0.0..=0.5).contains(&p.nu1)) {
        return Err(FitError::Model(format!("E1 {} MPa, nu1 {} outside the model", p.e1_mpa, p.nu1)));
    }
    let model = fw.model_shared(p.e1_mpa, p.nu1);
    let mu = p.contact_friction.unwrap_or(f64::INFINITY);
    let deltas: Vec<f64> = rec.samples.iter().map(|s| s.stage_mm - p.contact_offset_mm).collect();
    // At large strain the press is frictionless, as in the neo-Hookean
    // reference whose ratios scale it (a ratio taken between frictionless
    // presses applies to a frictionless press); friction acts in the twist.
    let normal = if p.large_strain { NormalContact::Frictionless } else { normal };
    let states: std::sync::Arc<Vec<fem::ContactState>> = match normal {
        // The gel and the indenter grip each other while the stage presses (the
        // same interface friction as in torsion), so the normal state depends on
        // the path: it is followed through the recording's depths in small steps.
        NormalContact::Frictional => {
            let deepest = deltas.iter().copied().fold(0.0, f64::max);
            model.normal_path_memo(&deltas, mu, (deepest / NORMAL_LOAD_STEPS).max(1e-6))?
        }
        NormalContact::Frictionless => {
            let mut solved: HashMap<u64, fem::ContactState> = HashMap::new();
            let mut out = Vec::with_capacity(deltas.len());
            for &delta in &deltas {
                let st = match solved.entry(delta.to_bits()) {
                    Entry::Occupied(e) => e.into_mut(),
                    Entry::Vacant(e) => e.insert(model.normal_memo(delta)?),
                };
                out.push(st.clone());
            }
            std::sync::Arc::new(out)
        }
    };
    // The large-strain ratios at this fit's materials, read at each sample's approach.
    let table = match p.large_strain {
        true => {
            Some(fem::hyper::LargeStrainTable::builtin()?.at_groups(&super::large_strain::groups(rec, p, layer, 0.0)))
        }
        false => None,
    };
    let mut out = Vec::with_capacity(rec.samples.len());
    // The torsion sweep twists the state at one depth many times: what its
    // twists share is prepared once per depth.
    // A sweep twists out and back through the same angles (and repeats):
    // each twist of a depth is solved once, the depth's twists in one
    // sweep (the model has no memory of the twist's path: every twist is
    // loaded monotonically from zero).
    let mut twists: HashMap<u64, (usize, Vec<f64>)> = HashMap::new();
    for (i, (s, &delta)) in rec.samples.iter().zip(&deltas).enumerate() {
        if s.phase == Phase::Torsion {
            let (_, at) = twists.entry(delta.to_bits()).or_insert((i, Vec::new()));
            at.push(s.rot_deg.to_radians().abs());
        }
    }
    let mut twisted: HashMap<(u64, u64), f64> = HashMap::new();
    for (delta, (first, mut at)) in twists {
        at.sort_by(f64::total_cmp);
        at.dedup();
        let theta1 = match model.twist_setup(&states[first], mu) {
            Some(setup) => model.theta1_rad_sweep(&setup, &at),
            None => vec![None; at.len()],
        };
        for (t, th) in at.iter().zip(theta1) {
            twisted.insert((delta, t.to_bits()), th.map_or(0.0, f64::to_degrees));
        }
    }
    for ((s, st), &delta) in rec.samples.iter().zip(states.iter()).zip(&deltas) {
        let theta1_deg = match s.phase {
            Phase::Normal => 0.0,
            Phase::Torsion => {
                let twist = s.rot_deg.to_radians();
                twisted.get(&(delta.to_bits(), twist.abs().to_bits())).copied().unwrap_or(0.0) * twist.signum()
            }
        };
        let (g1, t1) = match &table {
            Some(t) => {
                let d = super::large_strain::groups(rec, p, layer, delta).delta_over_r2;
                (t.gamma1_ratio(d).ratio, t.frictional_twist_ratio(d, s.rot_deg, mu).ratio)
            }
            None => (1.0, 1.0),
        };
        let gamma1_mm = st.gamma1_mm * g1;
        out.push(Prediction { gamma1_mm, theta1_deg: theta1_deg * t1, beta: (delta - gamma1_mm) / ind.r_mm });
    }
    Ok(out)
}

/// The frictional FE model minus its fast frictionless form at `p`, per sample,
/// with its derivatives in the parameters: the fit iterates on the fast form
/// plus this difference and refreshes it between passes. The derivatives
/// matter: friction acts on the data mostly through the difference, so with a
/// frozen difference the passes stall where the fast form alone is flat (on
/// our own noisy frictional recordings E1 came out 1-2 % low, the friction
/// 0.51 for 0.4; docs/physics.md). `None` without an FE layer.
///
/// The derivatives change slowly: a correction taken again near `previous`
/// (E1 within 0.5 %, nu1 within 0.005, friction within 10 %) keeps its derivatives and refreshes only the difference itself (the
/// passes' cost is then one frictional path each, not five).
pub(super) fn friction_correction(
    rec: &Recording,
    p: &ModelParams,
    previous: Option<&Correction>,
) -> Result<Option<Correction>, FitError> {
    // Without a layer there is nothing to correct; at large strain the press
    // is frictionless (see `predict_fe`), so the fast form is the model.
    let Some(layer) = fe_layer(rec).filter(|_| !p.large_strain) else {
        return Ok(None);
    };
    let diff = |q: &ModelParams| -> Result<Vec<(f64, f64)>, FitError> {
        let exact = predict_fe(rec, q, layer, NormalContact::Frictional)?;
        let fast = predict_fe(rec, q, layer, NormalContact::Frictionless)?;
        Ok(exact.iter().zip(&fast).map(|(e, f)| (e.gamma1_mm - f.gamma1_mm, e.theta1_deg - f.theta1_deg)).collect())
    };
    let at = physical(p);
    let near = |c: &&Correction| {
        c.at.len() == at.len()
            && (c.at[0] / at[0] - 1.0).abs() < 5e-3
            && (c.at[1] - at[1]).abs() < 5e-3
            && c.at.get(3).zip(at.get(3)).is_none_or(|(a, b)| (a / b - 1.0).abs() < 0.1)
    };
    if let Some(prev) = previous.filter(near) {
        return Ok(Some(Correction { at, base: diff(p)?, slope: prev.slope.clone() }));
    }
    // The difference at `p` and one step in each parameter: independent
    // frictional paths, followed on the cores there are (the same numbers as
    // one after the other).
    let steps: Vec<f64> = (0..at.len())
        .map(|j| match j {
            // Steps well above the path's own discretisation, inside the range.
            0 => 1e-3 * at[0],
            1 if at[1] + 2e-3 > 0.5 => -2e-3,
            1 => 2e-3,
            2 => 2e-4,
            _ => 0.02 * at[3],
        })
        .collect();
    let points: Vec<ModelParams> = std::iter::once(*p)
        .chain(steps.iter().enumerate().map(|(j, &step)| {
            let mut v = at.clone();
            v[j] += step;
            ModelParams {
                e1_mpa: v[0],
                nu1: v[1],
                contact_offset_mm: v[2],
                contact_friction: v.get(3).copied(),
                large_strain: p.large_strain,
            }
        }))
        .collect();
    let mut diffs = points.par_iter().map(diff).collect::<Result<Vec<_>, FitError>>()?.into_iter();
    let base = diffs.next().ok_or_else(|| FitError::Model("no friction correction was taken".into()))?;
    let slope = diffs
        .zip(&steps)
        .map(|(moved, &step)| moved.iter().zip(&base).map(|(m, b)| ((m.0 - b.0) / step, (m.1 - b.1) / step)).collect())
        .collect();
    Ok(Some(Correction { at, base, slope }))
}

/// Load steps from first touch to the deepest sample in the frictional normal
/// path (from 30 to 120 steps gamma1 moves by at most 0.4 µm on the dev set's
/// recordings, a fifth of their noise; docs/physics.md).
const NORMAL_LOAD_STEPS: f64 = 60.0;

#[cfg(test)]
mod tests {
    use super::friction_move;

    /// Below where it was taken the correction moves with the friction
    /// itself, above with its logarithm; the two meet with the same value and
    /// slope there, and far above the move grows only logarithmically (10⁴
    /// from a correction taken at 8.9: 62 in place of 9991).
    #[test]
    fn the_friction_move_is_linear_below_logarithmic_above_and_smooth_between() {
        let at = 0.4;
        assert_eq!(friction_move(at, at), 0.0);
        assert!((friction_move(0.1, at) - (0.1 - at)).abs() < 1e-15);
        assert!((friction_move(0.0, at) + at).abs() < 1e-15, "zero friction is a finite move");
        let h = 1e-6;
        let below = (friction_move(at, at) - friction_move(at - h, at)) / h;
        let above = (friction_move(at + h, at) - friction_move(at, at)) / h;
        assert!((below - 1.0).abs() < 1e-9 && (above - 1.0).abs() < 1e-5, "slopes {below} {above}");
        let far = friction_move(1e4, 8.9);
        assert!((far - 8.9 * (1e4f64 / 8.9).ln()).abs() < 1e-9 && far < 63.0, "{far}");
        let mut last = f64::NEG_INFINITY;
        for k in 0..200 {
            let m = friction_move(0.01 * 1.05f64.powi(k), at);
            assert!(m > last, "monotone");
            last = m;
        }
    }
}
