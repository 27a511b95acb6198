//! The declared layer's forward model in the fit (docs/fem.md, "The
//! tabulated law"; docs/physics.md, "Finite-element reference" and "Large
//! strain"): the project's FE reference of a hemisphere on a gel layer, with
//! Coulomb friction in both sweeps — its frictionless press and twist read
//! off the rig's tabulated law, plus what friction in the press adds, taken
//! on the FE model as a deferred correction — and at large strain the
//! tabulated ratios of the neo-Hookean reference (its press, its stuck twist
//! and its slip) on the frictionless press (friction then acts in the twist
//! only).

use std::collections::HashMap;
use std::collections::hash_map::Entry;

use rayon::prelude::*;
use sim::physics::Layer;
use sim::recording::{Phase, Recording};

use super::FitError;
use super::full::{ModelParams, Prediction, fe_layer};

/// Per-sample (gamma1 mm, theta1 deg) to add to the tabulated frictionless
/// law for what friction in the press adds (a deferred correction: see
/// [`friction_correction`]), linear in the parameters about where it was taken.
#[derive(Debug, Clone)]
pub(super) struct Correction {
    /// E1, nu1, z0 and friction where it was taken.
    at: Vec<f64>,
    base: Vec<(f64, f64)>,
    /// Its derivative in each of those parameters, per sample (none: taken
    /// at one point, or nothing to follow).
    slope: Vec<Vec<(f64, f64)>>,
    /// Where those derivatives were taken (they are kept while the passes
    /// stay near there).
    slopes_from: Vec<f64>,
    /// Whether it carries the press's friction (not at large strain, whose
    /// press is frictionless).
    press: bool,
    /// Whether its derivatives are the friction's alone (the others left at
    /// zero): a first set, to bring the passes near the optimum for a whole
    /// set to be taken there ([`friction_correction_in_friction`]).
    partial: bool,
}

impl Correction {
    /// No correction, at `p`: the fast form alone (the fit's first pass on a
    /// layer, before any frictional path is followed).
    pub(super) fn none(rec: &Recording, p: &ModelParams) -> Self {
        let at = physical(p);
        Correction {
            slopes_from: at.clone(),
            at,
            base: vec![(0.0, 0.0); rec.samples.len()],
            slope: Vec::new(),
            press: false,
            partial: false,
        }
    }

    /// Whether it was taken with derivatives (a value alone has none).
    pub(super) fn has_slopes(&self) -> bool {
        !self.slope.is_empty()
    }

    /// Whether its derivatives are the friction's alone.
    pub(super) fn is_partial(&self) -> bool {
        self.partial
    }

    /// This correction taken again at `at`, where what friction adds is
    /// `base`: its derivatives follow by a secant (Broyden) update, each
    /// sample's the least change that makes the linear form read `base` at
    /// `at` (the move measured in the finite differences' own steps). The
    /// passes move along the E1-nu1 ridge, where a derivative taken a few
    /// tenths of a percent away misplaces the optimum by a third of a
    /// standard error; the secant holds them to what the frictional paths
    /// do along that very move, and the derivatives stand where the last
    /// one was taken (docs/fem.md, "The passes").
    fn moved_to(&self, at: Vec<f64>, base: Vec<(f64, f64)>) -> Correction {
        let scale = step_sizes(&at);
        let mut dx: Vec<f64> = at.iter().zip(&self.at).map(|(a, b)| a - b).collect();
        if let (Some(m), Some(&from), Some(&to)) = (dx.get_mut(3), self.at.get(3), at.get(3)) {
            *m = friction_move(to, from);
        }
        let x: Vec<f64> = dx.iter().zip(&scale).map(|(d, s)| d / s.abs()).collect();
        let norm2: f64 = x.iter().map(|v| v * v).sum();
        let mut slope = self.slope.clone();
        if norm2 > 0.0 && slope.len() == dx.len() {
            for (i, (now, was)) in base.iter().zip(&self.base).enumerate() {
                let read = slope.iter().zip(&dx).fold(*was, |(g, t), (d, m)| (g + d[i].0 * m, t + d[i].1 * m));
                let miss = (now.0 - read.0, now.1 - read.1);
                for ((d, xj), sj) in slope.iter_mut().zip(&x).zip(&scale) {
                    let w = xj / norm2 / sj.abs();
                    d[i].0 += miss.0 * w;
                    d[i].1 += miss.1 * w;
                }
            }
        }
        Correction { slopes_from: at.clone(), at, base, slope, press: self.press, partial: false }
    }

    /// Whether it carries the press's friction (and so is taken again
    /// between passes): not at large strain, whose press is frictionless.
    pub(super) fn follows_friction(&self) -> bool {
        self.press
    }

    /// How far `p` lies from where the derivatives were taken: E1
    /// (relative) and nu1.
    pub(super) fn slopes_apart(&self, p: &ModelParams) -> [f64; 2] {
        [p.e1_mpa / self.slopes_from[0] - 1.0, p.nu1 - self.slopes_from[1]]
    }

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

/// The finite differences' step in each of E1, nu1, z0 and the friction
/// about `at`: well above the frictional path's own discretisation, inside
/// the range (nu1 steps down near 0.5).
fn step_sizes(at: &[f64]) -> Vec<f64> {
    (0..at.len())
        .map(|j| match j {
            0 => 1e-3 * at[0],
            1 if at[1] + 2e-3 > 0.5 => -2e-3,
            1 => 2e-3,
            2 => 2e-4,
            _ => 0.02 * at[3],
        })
        .collect()
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

/// The frictionless layer model read off the rig's tabulated law at every
/// sample (docs/fem.md, "The tabulated law"); `None` when a sample lies
/// outside the table (deeper than it reaches, or twisted further against the
/// friction), for the caller to solve the FE model instead.
fn predict_tabulated(
    rec: &Recording,
    p: &ModelParams,
    layer: Layer,
    fw: &fem::forward::Forward,
) -> Result<Option<Vec<Prediction>>, FitError> {
    // A rig whose law cannot be tabulated is solved on the FE model throughout.
    let Some(at) = fw.tabulated_over(p.e1_mpa, p.nu1, super::fe_law::twist_disc(p.large_strain)) else {
        return Ok(None);
    };
    let mu = p.contact_friction.unwrap_or(f64::INFINITY);
    let strain = strain_at(rec, p, layer)?;
    let mut out = Vec::with_capacity(rec.samples.len());
    for s in &rec.samples {
        let delta = s.stage_mm - p.contact_offset_mm;
        let (gamma1_mm, theta1_deg) = if delta <= 0.0 {
            (0.0, 0.0)
        } else {
            let Some(gamma1_mm) = at.gamma1_mm(delta) else {
                return Ok(None);
            };
            let theta1_deg = match s.phase {
                Phase::Normal => 0.0,
                Phase::Torsion => match at.theta1_rad(delta, s.rot_deg.to_radians(), mu) {
                    Some(t) => t.to_degrees(),
                    None => return Ok(None),
                },
            };
            (gamma1_mm, theta1_deg)
        };
        out.push(strained(rec, p, layer, strain.as_ref(), s, delta, gamma1_mm, theta1_deg));
    }
    Ok(Some(out))
}

/// The frictionless press of the project's own FE layer model (docs/fem.md):
/// a hemisphere held at its flat face on a gel layer, its twist limited by
/// Coulomb friction, read off the rig's tabulated law, and solved on the FE
/// model where a sample lies outside the table. What friction in the press
/// adds to it: [`friction_correction`].
pub(super) fn predict_fe(rec: &Recording, p: &ModelParams, layer: Layer) -> Result<Vec<Prediction>, FitError> {
    let ind = rec.meta.indenter;
    let fw = crate::layer::forward(&layer, ind.e_mpa, ind.nu, ind.r_mm)?;
    if !(p.e1_mpa.is_finite() && p.e1_mpa > 0.0 && (0.0..=0.5).contains(&p.nu1)) {
        return Err(FitError::Model(format!("E1 {} MPa, nu1 {} outside the model", p.e1_mpa, p.nu1)));
    }
    if let Some(pred) = predict_tabulated(rec, p, layer, &fw)? {
        return Ok(pred);
    }
    let model = fw.model_shared(p.e1_mpa, p.nu1);
    // What taking the mesh to zero element size adds, as the table has it
    // (docs/physics.md, "Mesh convergence"); none off its materials.
    let limit = fw.tabulated_at(p.e1_mpa, p.nu1);
    let mesh_term = |delta: f64| limit.as_ref().and_then(|t| t.mesh_gamma1_mm(delta)).unwrap_or(0.0);
    let mu = p.contact_friction.unwrap_or(f64::INFINITY);
    let deltas: Vec<f64> = rec.samples.iter().map(|s| s.stage_mm - p.contact_offset_mm).collect();
    // At large strain the press is frictionless, as in the neo-Hookean
    // reference whose ratios scale it (a ratio taken between frictionless
    // presses applies to a frictionless press); friction acts in the twist.
    // Each sample's gamma1, and the state at each depth the torsion sweep twists.
    let mut twist_states: HashMap<u64, fem::ContactState> = HashMap::new();
    let mut solved: HashMap<u64, f64> = HashMap::new();
    let mut gamma1 = Vec::with_capacity(deltas.len());
    for (s, &delta) in rec.samples.iter().zip(&deltas) {
        let g = match solved.entry(delta.to_bits()) {
            Entry::Occupied(e) => *e.get(),
            Entry::Vacant(e) => {
                let st = model.normal_memo(delta)?;
                let g = *e.insert(st.gamma1_mm + if delta > 0.0 { mesh_term(delta) } else { 0.0 });
                if s.phase == Phase::Torsion {
                    twist_states.insert(delta.to_bits(), st);
                }
                g
            }
        };
        if s.phase == Phase::Torsion && !twist_states.contains_key(&delta.to_bits()) {
            twist_states.insert(delta.to_bits(), model.normal_memo(delta)?);
        }
        gamma1.push(g);
    }
    // The large-strain ratios at this fit's materials, read at each sample's approach.
    let strain = strain_at(rec, p, layer)?;
    let mut out = Vec::with_capacity(rec.samples.len());
    // The torsion sweep twists the state at one depth many times: what its
    // twists share is prepared once per depth.
    // A sweep twists out and back through the same angles (and repeats):
    // each twist of a depth is solved once, the depth's twists in one
    // sweep (the model has no memory of the twist's path: every twist is
    // loaded monotonically from zero).
    let mut twists: HashMap<u64, Vec<f64>> = HashMap::new();
    for (s, &delta) in rec.samples.iter().zip(&deltas) {
        if s.phase == Phase::Torsion {
            twists.entry(delta.to_bits()).or_default().push(s.rot_deg.to_radians().abs());
        }
    }
    let mut twisted: HashMap<(u64, u64), f64> = HashMap::new();
    for (delta, mut at) in twists {
        at.sort_by(f64::total_cmp);
        at.dedup();
        let disc = super::fe_law::twist_disc(p.large_strain);
        let theta1 = match twist_states.get(&delta).and_then(|st| model.twist_setup_over(st, mu, disc)) {
            Some(setup) => model.theta1_rad_sweep(&setup, &at),
            None => vec![None; at.len()],
        };
        for (t, th) in at.iter().zip(theta1) {
            twisted.insert((delta, t.to_bits()), th.map_or(0.0, f64::to_degrees));
        }
    }
    for ((s, g), &delta) in rec.samples.iter().zip(&gamma1).zip(&deltas) {
        let theta1_deg = match s.phase {
            Phase::Normal => 0.0,
            Phase::Torsion => {
                let twist = s.rot_deg.to_radians();
                twisted.get(&(delta.to_bits(), twist.abs().to_bits())).copied().unwrap_or(0.0) * twist.signum()
            }
        };
        out.push(strained(rec, p, layer, strain.as_ref(), s, delta, *g, theta1_deg));
    }
    Ok(out)
}

/// The large-strain table's interpolation at `p`'s materials; `None` at
/// small strain.
fn strain_at(
    rec: &Recording,
    p: &ModelParams,
    layer: Layer,
) -> Result<Option<fem::hyper::AtGroups<'static>>, FitError> {
    Ok(match p.large_strain {
        true => {
            Some(fem::hyper::LargeStrainTable::builtin()?.at_groups(&super::large_strain::groups(rec, p, layer, 0.0)))
        }
        false => None,
    })
}

/// Sample `s`'s prediction at approach `delta_mm` from the linear model's
/// gamma1 and theta1 there, at large strain (`strain`) scaled by the
/// neo-Hookean reference's ratios at that approach (the twist's under the
/// fit's friction).
#[allow(clippy::too_many_arguments)]
fn strained(
    rec: &Recording,
    p: &ModelParams,
    layer: Layer,
    strain: Option<&fem::hyper::AtGroups<'static>>,
    s: &sim::recording::Sample,
    delta_mm: f64,
    gamma1_mm: f64,
    theta1_deg: f64,
) -> Prediction {
    let (g1, t1) = match strain {
        Some(t) => {
            let d = super::large_strain::groups(rec, p, layer, delta_mm).delta_over_r2;
            let mu = p.contact_friction.unwrap_or(f64::INFINITY);
            (t.gamma1_ratio(d).ratio, t.frictional_twist_ratio(d, s.rot_deg, mu).ratio)
        }
        None => (1.0, 1.0),
    };
    let gamma1_mm = gamma1_mm * g1;
    Prediction { gamma1_mm, theta1_deg: theta1_deg * t1, beta: (delta_mm - gamma1_mm) / rec.meta.indenter.r_mm }
}

/// What friction in the press adds at `p` ([`friction_added`]), per sample,
/// with its derivatives in the parameters: the fit iterates on the tabulated
/// frictionless law plus this and refreshes it between passes. The
/// derivatives matter: friction acts on the data mostly through it, so with
/// a frozen correction the passes stall where the frictionless law alone is
/// flat (on our own noisy frictional recordings E1 came out 1-2 % low, the
/// friction 0.51 for 0.4; docs/physics.md). `None` without an FE layer; at
/// large strain (a frictionless press) a correction of nothing.
///
/// The derivatives change slowly: a correction taken again near `previous`
/// (E1 within 0.5 %, nu1 within 0.005, friction within 10 %; not one with the
/// friction's derivative alone) takes the difference itself again and
/// follows its derivatives by a secant update ([`Correction::moved_to`]; the
/// passes' cost is then one frictional path each, not five).
pub(super) fn friction_correction(
    rec: &Recording,
    p: &ModelParams,
    previous: Option<&Correction>,
) -> Result<Option<Correction>, FitError> {
    // Without a layer there is nothing to correct.
    let Some(layer) = fe_layer(rec) else {
        return Ok(None);
    };
    let at = physical(p);
    // At large strain the press is frictionless (see `predict_fe`): friction
    // acts in the twist alone, which the tabulated form carries.
    if p.large_strain {
        return Ok(Some(Correction::none(rec, p)));
    }
    let near = |c: &&Correction| {
        c.at.len() == at.len()
            && !c.partial
            && c.slope.len() == at.len()
            && (c.at[0] / at[0] - 1.0).abs() < 5e-3
            && (c.at[1] - at[1]).abs() < 5e-3
            && c.at.get(3).zip(at.get(3)).is_none_or(|(a, b)| (a / b - 1.0).abs() < 0.1)
    };
    if let Some(prev) = previous.filter(near) {
        // Taken at this very point (the passes go on from where the
        // derivatives were just taken again): it is what it was, bit for bit.
        if prev.at == at {
            return Ok(Some(prev.clone()));
        }
        return Ok(Some(prev.moved_to(at, friction_added(rec, p, layer)?)));
    }
    taken_with_slopes(rec, p, layer, at, false)
}

/// [`friction_correction`] with the friction's derivative alone (two
/// frictional paths, one round on two cores, where the whole set is five):
/// the fit's first set, taken where its first pass ended, often a few
/// tenths of a standard error from the optimum. Friction acts on the data
/// mostly through what it adds, so with this the next pass comes near the
/// optimum, and the whole set is taken there (docs/fem.md, "The passes").
pub(super) fn friction_correction_in_friction(
    rec: &Recording,
    p: &ModelParams,
) -> Result<Option<Correction>, FitError> {
    let Some(layer) = fe_layer(rec) else {
        return Ok(None);
    };
    if p.large_strain {
        return Ok(Some(Correction::none(rec, p)));
    }
    let at = physical(p);
    taken_with_slopes(rec, p, layer, at, true)
}

/// The correction at `p` (whose physical parameters are `at`) with its
/// derivatives in every parameter, or in the friction alone (`partial`; the
/// others then zero).
fn taken_with_slopes(
    rec: &Recording,
    p: &ModelParams,
    layer: Layer,
    at: Vec<f64>,
    partial: bool,
) -> Result<Option<Correction>, FitError> {
    // The difference at `p` and one step in each parameter: independent
    // frictional paths, followed on the cores there are (the same numbers as
    // one after the other).
    let stepped = |j: usize| !partial || j == 3;
    let steps = step_sizes(&at);
    let points: Vec<ModelParams> = std::iter::once(*p)
        .chain(steps.iter().enumerate().filter(|(j, _)| stepped(*j)).map(|(j, &step)| {
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
    let mut diffs =
        points.par_iter().map(|q| friction_added(rec, q, layer)).collect::<Result<Vec<_>, FitError>>()?.into_iter();
    let base = diffs.next().ok_or_else(|| FitError::Model("no friction correction was taken".into()))?;
    let slope = steps
        .iter()
        .enumerate()
        .map(|(j, &step)| match stepped(j) {
            true => diffs
                .next()
                .map(|moved| moved.iter().zip(&base).map(|(m, b)| ((m.0 - b.0) / step, (m.1 - b.1) / step)).collect()),
            false => Some(vec![(0.0, 0.0); base.len()]),
        })
        .collect::<Option<Vec<Vec<(f64, f64)>>>>()
        .ok_or_else(|| FitError::Model("a derivative of the friction correction was not taken".into()))?;
    Ok(Some(Correction { slopes_from: at.clone(), at, base, slope, press: true, partial }))
}

/// What friction adds to the FE layer model at `q`, per sample: the
/// frictional press and the twist of its state, less the frictionless ones,
/// both solved on the same mesh at the same approaches (their node-to-node
/// steps cancel; docs/fem.md, "The tabulated law"). The layer model is the
/// tabulated frictionless law plus this. The gel and the indenter grip each
/// other while the stage presses, so the frictional state depends on the
/// path: it is followed from first touch in even steps of the approach and
/// read at each sample between them (docs/fem.md, "The passes").
fn friction_added(rec: &Recording, q: &ModelParams, layer: Layer) -> Result<Vec<(f64, f64)>, FitError> {
    let ind = rec.meta.indenter;
    let fw = crate::layer::forward(&layer, ind.e_mpa, ind.nu, ind.r_mm)?;
    if !(q.e1_mpa.is_finite() && q.e1_mpa > 0.0 && (0.0..=0.5).contains(&q.nu1)) {
        return Err(FitError::Model(format!("E1 {} MPa, nu1 {} outside the model", q.e1_mpa, q.nu1)));
    }
    let model = fw.model_shared(q.e1_mpa, q.nu1);
    let mu = q.contact_friction.unwrap_or(f64::INFINITY);
    let deltas: Vec<f64> = rec.samples.iter().map(|s| s.stage_mm - q.contact_offset_mm).collect();
    let deepest = deltas.iter().copied().fold(0.0, f64::max);
    // The twists of each depth the torsion sweep holds.
    let mut twists: HashMap<u64, Vec<f64>> = HashMap::new();
    for (s, &d) in rec.samples.iter().zip(&deltas) {
        if s.phase == Phase::Torsion && d > 0.0 {
            twists.entry(d.to_bits()).or_default().push(s.rot_deg.to_radians().abs());
        }
    }
    // The path stops at even steps of the approach, a sixtieth of the
    // deepest stage reading apart, as far as the deepest sample (and the
    // step beyond it): what friction adds is smooth in the approach and is
    // read at each sample between the stops. The stops do not move with the
    // contact offset z0 (it moves where the samples lie among them): a path
    // stopped at the samples' own depths changed its stick and slip at the
    // contact's edge with every tenth of a micrometre of z0, its correction
    // stepping by 0.1 µm of gamma1 and 0.6 mdeg of theta1, so that its
    // derivative in z0 was noise and the fit's passes wandered by up to a
    // standard error on the simulated rig's recording (docs/fem.md, "The
    // passes").
    let stage_deepest = rec.samples.iter().map(|s| s.stage_mm).fold(0.0, f64::max);
    let step = stage_deepest.max(1e-3) / NORMAL_LOAD_STEPS;
    let count = (deepest / step).ceil().max(0.0) as usize;
    if count > 4 * NORMAL_LOAD_STEPS as usize {
        return Err(FitError::Model(format!(
            "a contact offset of {:.4} mm lies far outside the recording's stage readings",
            q.contact_offset_mm
        )));
    }
    let stops: Vec<f64> = (1..=count).map(|k| k as f64 * step).collect();
    let path = model.normal_path_memo(&stops, mu, step)?;
    let plain: Vec<fem::ContactState> = stops.iter().map(|&d| model.normal_memo(d)).collect::<Result<_, _>>()?;
    // What friction adds to gamma1 at each stop, none at first touch.
    let nodes: Vec<(f64, f64)> = std::iter::once((0.0, 0.0))
        .chain(stops.iter().zip(path.iter().zip(&plain)).map(|(&d, (f, p))| (d, f.gamma1_mm - p.gamma1_mm)))
        .collect();
    // ... and to each twist of a held depth, at the stops either side of it
    // (none at first touch), linear between them.
    let mut at_stop: HashMap<(usize, u64), f64> = HashMap::new();
    let mut twist_added: HashMap<(u64, u64), f64> = HashMap::new();
    for (d, mut at) in twists {
        at.sort_by(f64::total_cmp);
        at.dedup();
        let depth = f64::from_bits(d);
        let above = ((depth / step).ceil() as usize).clamp(1, stops.len().max(1));
        let w = ((depth - (above - 1) as f64 * step) / step).clamp(0.0, 1.0);
        for k in [above - 1, above] {
            if k == 0 || at.iter().all(|t| at_stop.contains_key(&(k, t.to_bits()))) {
                continue;
            }
            let (Some(pressed), Some(free)) = (path.get(k - 1), plain.get(k - 1)) else {
                return Err(FitError::Model("a held depth of the torsion sweep lies beyond the path".into()));
            };
            let sweep = |st: &fem::ContactState| match model.twist_setup(st, mu) {
                Some(setup) => model.theta1_rad_sweep(&setup, &at),
                None => vec![None; at.len()],
            };
            for ((t, a), b) in at.iter().zip(sweep(pressed)).zip(sweep(free)) {
                at_stop.insert((k, t.to_bits()), (a.unwrap_or(0.0) - b.unwrap_or(0.0)).to_degrees());
            }
        }
        for t in &at {
            let read = |k: usize| if k == 0 { 0.0 } else { at_stop.get(&(k, t.to_bits())).copied().unwrap_or(0.0) };
            twist_added.insert((d, t.to_bits()), (1.0 - w) * read(above - 1) + w * read(above));
        }
    }
    Ok(rec
        .samples
        .iter()
        .zip(&deltas)
        .map(|(s, &d)| {
            let gamma1 = if d > 0.0 { cubic_through(&nodes, d) } else { 0.0 };
            let theta1 = match s.phase {
                Phase::Normal => 0.0,
                Phase::Torsion => {
                    let twist = s.rot_deg.to_radians();
                    twist_added.get(&(d.to_bits(), twist.abs().to_bits())).copied().unwrap_or(0.0) * twist.signum()
                }
            };
            (gamma1, theta1)
        })
        .collect())
}

/// The cubic through the four nodes around `x` (sorted by their first
/// entry; fewer where there are fewer), at `x`: a node's own value there.
fn cubic_through(nodes: &[(f64, f64)], x: f64) -> f64 {
    let n = nodes.len();
    if n == 0 {
        return 0.0;
    }
    let above = nodes.partition_point(|p| p.0 < x);
    if let Some(p) = nodes.get(above).filter(|p| p.0 == x) {
        return p.1;
    }
    let lo = above.saturating_sub(2).min(n.saturating_sub(4));
    let near = &nodes[lo..(lo + 4).min(n)];
    near.iter()
        .enumerate()
        .map(|(i, &(xi, yi))| {
            let w: f64 =
                near.iter().enumerate().filter(|&(j, _)| j != i).map(|(_, &(xj, _))| (x - xj) / (xi - xj)).product();
            w * yi
        })
        .sum()
}

/// The friction correction at `p` without its derivatives (what the layer
/// model predicts with at one point: the tabulated form plus it), `None`
/// without a layer.
pub(super) fn friction_at(rec: &Recording, p: &ModelParams) -> Result<Option<Correction>, FitError> {
    let Some(layer) = fe_layer(rec) else {
        return Ok(None);
    };
    if p.large_strain {
        return Ok(Some(Correction::none(rec, p)));
    }
    let at = physical(p);
    Ok(Some(Correction {
        slopes_from: at.clone(),
        at,
        base: friction_added(rec, p, layer)?,
        slope: Vec::new(),
        press: true,
        partial: false,
    }))
}

/// Load steps from first touch to the deepest stage reading in the
/// frictional normal path (from 30 to 120 steps gamma1 moves by at most 0.4
/// µm on the dev set's recordings, a fifth of their noise; docs/physics.md).
const NORMAL_LOAD_STEPS: f64 = 60.0;

#[cfg(test)]
mod tests {
    use super::*;

    /// What friction adds moves smoothly with the contact offset z0: over
    /// steps of 0.1 µm its change at the deepest press and at a 3° twist
    /// keeps its slope, so that the fit's finite difference in z0 (0.2 µm)
    /// is a derivative. A path stopped at the samples' own depths (which
    /// move with z0) stepped at every tenth of a micrometre, by about 0.1
    /// µm of gamma1 and 0.6 mdeg of theta1 on the simulated rig's gel, where
    /// the slope is 0.0005 µm and 0.002 mdeg a step.
    #[test]
    fn what_friction_adds_is_smooth_in_the_contact_offset() {
        let rec = crate::fit::dev_recording("tableI_3_E2-3.0_nu2-0.40.csv");
        let layer = fe_layer(&rec).unwrap();
        let deep = (0..rec.samples.len())
            .filter(|&i| rec.samples[i].phase == Phase::Normal)
            .max_by(|&a, &b| rec.samples[a].stage_mm.total_cmp(&rec.samples[b].stage_mm))
            .unwrap();
        let twist = rec.samples.iter().position(|s| s.phase == Phase::Torsion && s.rot_deg.abs() > 2.5).unwrap();
        let added: Vec<(f64, f64)> = (-5..=5)
            .map(|k| {
                let q = ModelParams {
                    e1_mpa: 1.0,
                    nu1: 0.48,
                    contact_offset_mm: 1e-4 * k as f64,
                    contact_friction: Some(0.4),
                    large_strain: false,
                };
                let c = friction_added(&rec, &q, layer).unwrap();
                (c[deep].0 * 1e3, c[twist].1 * 1e3)
            })
            .collect();
        let steps = |f: fn(&(f64, f64)) -> f64| -> Vec<f64> { added.windows(2).map(|w| f(&w[1]) - f(&w[0])).collect() };
        for (what, d, floor) in [("gamma1 µm", steps(|v| v.0), 2e-3), ("theta1 mdeg", steps(|v| v.1), 0.02)] {
            let mut sorted = d.clone();
            sorted.sort_by(f64::total_cmp);
            let median = sorted[sorted.len() / 2];
            let worst = d.iter().map(|v| (v - median).abs()).fold(0.0, f64::max);
            println!("{what}: steps {d:.5?}");
            assert!(worst <= 0.2 * median.abs() + floor, "{what}: a step {worst} off the median step {median}");
        }
    }

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
