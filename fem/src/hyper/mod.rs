//! Large strain (docs/physics.md, "Large strain"): both bodies compressible
//! neo-Hookean, W = mu/2 (I1 - 3 - 2 ln J) + lambda/2 (ln J)², total Lagrangian on
//! the same quadrilateral meshes as the linear reference, and frictionless
//! contact on the deformed surfaces (the gel's surface nodes against the
//! indenter's surface segments, exact normal gaps, Lagrange multipliers with an
//! active set). Torsion is the small twist of the deformed state.
//!
//! The energy is split as the linear elements split it: the part that stiffens
//! volume, K/2 (ln J)² with K = lambda + 2 mu / 3, is integrated at the element
//! centre; the rest, mu/2 (I1 - 3 - 2 ln J) - mu/3 (ln J)², at 2x2 Gauss points.
//! The sum is the neo-Hookean energy above, and at small strain each element is
//! exactly the linear one (`elastic.rs`), so the two models differ only by the
//! large-strain physics.
//!
//! Under the large compression beneath a stiff indenter's tip that element's
//! hourglass modes give way (negative pivots in the gel's tangent, then an
//! iteration that no longer settles), well short of the physics' limit.
//! `Integration::Full` puts the volumetric part at the 2x2 points too: it
//! locks slightly but follows the press to the indenter's flank, and the
//! large-strain table uses its ratios' increments to continue the selective
//! ones in depth (docs/physics.md, "Large strain").

use std::f64::consts::PI;

mod body;
mod sweep;
mod table;
mod twist;

pub use body::HyperBody;
pub use sweep::{Sweep, SweepPlan, calibration_sweep, converged_layer_sweep};
pub use table::{AtGroups, Groups, LargeStrainTable, Lookup, TABLE_COARSE_MM, TABLE_FINE_MM, mesh_extrapolated};

use crate::FemError;
use crate::banded::Factor;
use crate::dense;
use crate::elastic::{Integration, Material};
use crate::mesh::Mesh;

/// Newton stops when no displacement moves by more than this, mm.
const TOLERANCE_MM: f64 = 2e-7;
/// ... or by more than this after `STALL_ROUNDS` fresh tangents, mm (a tenth of a
/// micrometre: a twentieth of a sensor's noise).
const STALL_TOLERANCE_MM: f64 = 1e-4;
const STALL_ROUNDS: usize = 3;
/// ... or by more than this after `LATE_ROUNDS` (half a micrometre, a quarter of
/// a sensor's noise): deep in a stiff indenter's sweep the contact edge sits on
/// the steep flank of the sphere, where a node on a corner of the indenter's
/// chain holds the iteration at a few tenths of a micrometre.
const LATE_TOLERANCE_MM: f64 = 5e-4;
const LATE_ROUNDS: usize = 8;

/// The indenter's surface as a chain of nodes from the tip to the equator.
fn sphere_chain(mesh: &Mesh, radius_mm: f64) -> Vec<usize> {
    let mut on: Vec<(f64, usize)> = mesh
        .xy
        .iter()
        .enumerate()
        .filter(|(_, p)| ((p[0] * p[0] + (radius_mm - p[1]).powi(2)).sqrt() - radius_mm).abs() < 1e-9 * radius_mm)
        .map(|(n, p)| (p[0].atan2(radius_mm - p[1]), n))
        .collect();
    on.sort_by(|a, b| a.0.total_cmp(&b.0));
    on.into_iter().map(|(_, n)| n).collect()
}

/// A constraint's coefficients on one body's free dofs: (dof, coefficient).
type Row = Vec<(usize, f64)>;

/// Where a gel surface node meets the indenter: segment `m` of the chain, the
/// point's parameter `xi` on it, the segment's outward normal and the gap.
#[derive(Debug, Clone, Copy)]
struct Projection {
    m: usize,
    xi: f64,
    normal: [f64; 2],
    gap: f64,
}

/// The indenter's contact surface at one configuration: the chain's points
/// and its nodal normals.
struct ChainSurface {
    pts: Vec<[f64; 2]>,
    normals: Vec<[f64; 2]>,
}

/// A round's factored tangents and constraint rows (kept while the iteration contracts).
struct Frozen<'a> {
    kg: &'a Factor,
    ki: &'a Factor,
    rows: &'a [(Row, Row)],
}

/// One solved large-strain contact state.
#[derive(Debug, Clone, PartialEq)]
pub struct LargeState {
    pub delta_mm: f64,
    pub force_n: f64,
    pub gamma1_mm: f64,
    pub gamma2_mm: f64,
    /// Current radius of the outermost gel node in contact, mm.
    pub contact_radius_mm: f64,
    /// Contact force per radian on each gel surface node (0 off contact), N/rad.
    pub nodal_force: Vec<f64>,
    /// Current radius of each gel surface node, mm.
    pub radius_mm: Vec<f64>,
    /// Where each node in contact meets the indenter's chain (segment, parameter).
    meets: Vec<Option<(usize, f64)>>,
}

/// The gel and the indenter, both neo-Hookean, pressed together frictionlessly.
pub struct LargeStrainContact {
    pub gel: HyperBody,
    pub indenter: HyperBody,
    slaves: Vec<usize>,
    chain: Vec<usize>,
    delta_mm: f64,
    lambda: Vec<f64>,
}

impl LargeStrainContact {
    /// [`Self::new`] on elements that integrate their volumetric part as
    /// `integration` says (`Full`: stable under the large compression that
    /// stops the selective element; the table's extension in depth).
    pub fn with_integration(
        gel_mesh: Mesh,
        gel: Material,
        hemisphere: Mesh,
        indenter: Material,
        indenter_radius_mm: f64,
        integration: Integration,
    ) -> Result<Self, FemError> {
        let mut c = Self::new(gel_mesh, gel, hemisphere, indenter, indenter_radius_mm)?;
        c.gel.integration = integration;
        c.indenter.integration = integration;
        Ok(c)
    }

    /// `gel_mesh` with its surface on z = 0, the hemisphere of radius
    /// `indenter_radius_mm` with its tip at z = 0 (both as `Mesh` builds them).
    pub fn new(
        gel_mesh: Mesh,
        gel: Material,
        hemisphere: Mesh,
        indenter: Material,
        indenter_radius_mm: f64,
    ) -> Result<Self, FemError> {
        let slaves: Vec<usize> =
            gel_mesh.surface.iter().copied().filter(|&n| gel_mesh.xy[n][0] < 0.97 * indenter_radius_mm).collect();
        let chain = sphere_chain(&hemisphere, indenter_radius_mm);
        if chain.len() < 3 || slaves.is_empty() {
            return Err(FemError::Invalid("the indenter's surface or the gel's contact nodes are missing".into()));
        }
        let n = slaves.len();
        Ok(Self {
            gel: HyperBody::new(gel_mesh, gel)?,
            indenter: HyperBody::new(hemisphere, indenter)?,
            slaves,
            chain,
            delta_mm: 0.0,
            lambda: vec![0.0; n],
        })
    }

    /// Where each gel node meets the indenter's surface (see
    /// [`LargeStrainContact::project_on`]), on the current surfaces.
    fn project_all(&self) -> Vec<Projection> {
        let surface = self.chain_surface();
        self.slaves.iter().map(|&s| self.project_on(&surface, s)).collect()
    }

    /// The indenter's chain as it stands: its points and nodal normals (the
    /// mean of the two segments' at a node; vertical on the axis).
    fn chain_surface(&self) -> ChainSurface {
        let pts: Vec<[f64; 2]> = self.chain.iter().map(|&n| self.indenter.x(n)).collect();
        let seg_normal = |m: usize| {
            let t = [pts[m + 1][0] - pts[m][0], pts[m + 1][1] - pts[m][1]];
            let len = t[0].hypot(t[1]);
            [t[1] / len, -t[0] / len]
        };
        let nseg = pts.len() - 1;
        let normals = (0..pts.len())
            .map(|k| {
                let (p, q) = (seg_normal(k.saturating_sub(1).min(nseg - 1)), seg_normal(k.min(nseg - 1)));
                // On the axis the surface is symmetric: its normal is vertical.
                let v = if k == 0 { [0.0, p[1]] } else { [p[0] + q[0], p[1] + q[1]] };
                let len = v[0].hypot(v[1]);
                [v[0] / len, v[1] / len]
            })
            .collect();
        ChainSurface { pts, normals }
    }

    /// Where gel node `s` meets the indenter's `surface`, the chain of
    /// segments with normals interpolated between nodal normals, so the gap
    /// and its direction are continuous as a node slides over the chain's
    /// corners: the point is where the line along the interpolated normal
    /// through the node crosses the segment.
    fn project_on(&self, surface: &ChainSurface, s: usize) -> Projection {
        let xs = self.gel.x(s);
        let (pts, normals) = (&surface.pts, &surface.normals);
        let nseg = pts.len() - 1;
        let node_normal = |k: usize| normals[k];
        let at = |m: usize, xi: f64| {
            let (na, nb) = (node_normal(m), node_normal(m + 1));
            let v = [(1.0 - xi) * na[0] + xi * nb[0], (1.0 - xi) * na[1] + xi * nb[1]];
            let len = v[0].hypot(v[1]);
            let n = [v[0] / len, v[1] / len];
            let c = [pts[m][0] + xi * (pts[m + 1][0] - pts[m][0]), pts[m][1] + xi * (pts[m + 1][1] - pts[m][1])];
            let d = [xs[0] - c[0], xs[1] - c[1]];
            // Cross product: zero where the node lies on the normal's line.
            (d[0] * n[1] - d[1] * n[0], d[0] * n[0] + d[1] * n[1], n)
        };
        let mut best: Option<Projection> = None;
        for m in 0..nseg {
            let (h0, _, _) = at(m, 0.0);
            let (h1, _, _) = at(m, 1.0);
            if h0 * h1 > 0.0 && h0 != 0.0 {
                continue;
            }
            // Bisection on [0, 1] for the crossing (an end that is one already is
            // taken as it is: the node on the axis sits on the tip's normal).
            let xi = if h0 == 0.0 {
                0.0
            } else if h1 == 0.0 {
                1.0
            } else {
                let (mut lo, mut hi) = (0.0, 1.0);
                for _ in 0..50 {
                    let mid = 0.5 * (lo + hi);
                    let (hm, _, _) = at(m, mid);
                    if (hm < 0.0) == (h0 < 0.0) {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                0.5 * (lo + hi)
            };
            let (_, gap, normal) = at(m, xi);
            if best.as_ref().is_none_or(|b| gap.abs() < b.gap.abs()) {
                best = Some(Projection { m, xi, normal, gap });
            }
        }
        best.unwrap_or(Projection { m: 0, xi: 0.0, normal: [0.0, -1.0], gap: f64::INFINITY })
    }

    /// The gap's row on one body's free dofs: (dof, coefficient) pairs.
    fn gap_rows(&self, s: usize, pr: &Projection) -> (Row, Row) {
        let mut g = Vec::new();
        for c in 0..2 {
            if let Some(d) = self.gel.dof[s][c] {
                g.push((d, pr.normal[c]));
            }
        }
        let mut i = Vec::new();
        for (node, w) in [(self.chain[pr.m], 1.0 - pr.xi), (self.chain[pr.m + 1], pr.xi)] {
            for c in 0..2 {
                if let Some(d) = self.indenter.dof[node][c] {
                    i.push((d, w * pr.normal[c]));
                }
            }
        }
        (g, i)
    }

    /// Moves the platform to approach `delta_mm` (from the current one, in one
    /// step) and solves the contact there.
    ///
    /// Newton's method on the bodies with the contact's Lagrange multipliers: each
    /// body's tangent is factored at the start of a round and kept while the
    /// iteration contracts (the residual is always the exact one: current
    /// normals, current gaps), and the contact constraints are condensed onto the
    /// multipliers (a small dense system per iteration).
    pub fn step_to(&mut self, delta_mm: f64) -> Result<LargeState, FemError> {
        if !delta_mm.is_finite() || delta_mm < 0.0 {
            return Err(FemError::Invalid(format!("approach {delta_mm} mm")));
        }
        // Predictor: the whole indenter moves with the platform.
        let shift = delta_mm - self.delta_mm;
        self.indenter.u.iter_mut().for_each(|u| u[1] -= shift);
        self.delta_mm = delta_mm;
        let ns = self.slaves.len();
        let mut active: Vec<bool> = self.lambda.iter().map(|&l| l > 0.0).collect();
        let mut total = 0;
        for round in 0..40 {
            let (kg, ki) = (self.gel.tangent()?, self.indenter.tangent()?);
            let proj0 = self.project_all();
            if round == 0 {
                for k in 0..ns {
                    active[k] |= proj0[k].gap < 0.0;
                }
            }
            let rows0: Vec<_> = (0..ns).map(|k| self.gap_rows(self.slaves[k], &proj0[k])).collect();
            let mut cols: Vec<Option<(Vec<f64>, Vec<f64>)>> = vec![None; ns];
            let mut prev = f64::INFINITY;
            let mut history: Vec<(Vec<f64>, Vec<f64>)> = Vec::new();
            let mut last_active = active.clone();
            for _ in 0..40 {
                total += 1;
                let (_, fg) = self.gel.assemble(false, false)?;
                let (_, fi) = self.indenter.assemble(false, false)?;
                let proj = self.project_all();
                // Right-hand sides with the current normals and multipliers.
                let mut rg: Vec<f64> = fg.iter().map(|v| -v).collect();
                let mut ri: Vec<f64> = fi.iter().map(|v| -v).collect();
                for k in (0..ns).filter(|&k| self.lambda[k] != 0.0) {
                    let (g, i) = self.gap_rows(self.slaves[k], &proj[k]);
                    g.iter().for_each(|&(d, c)| rg[d] += self.lambda[k] * c);
                    i.iter().for_each(|&(d, c)| ri[d] -= self.lambda[k] * c);
                }
                let (ag, ai) = (kg.solve(&rg), ki.solve(&ri));
                let frozen = Frozen { kg: &kg, ki: &ki, rows: &rows0 };
                let dlam = self
                    .multipliers(&frozen, &mut cols, &proj, &ag, &ai, &mut active)
                    .ok_or(FemError::ContactNotSettled(total))?;
                let mut dg = ag;
                let mut di = ai;
                for k in (0..ns).filter(|&k| dlam[k] != 0.0) {
                    if let Some((cg, ci)) = &cols[k] {
                        dg.iter_mut().zip(cg).for_each(|(d, c)| *d += dlam[k] * c);
                        di.iter_mut().zip(ci).for_each(|(d, c)| *d -= dlam[k] * c);
                    }
                }
                let size = dg.iter().chain(&di).fold(0.0f64, |m, v| m.max(v.abs()));
                // The iteration as a fixed-point map x -> x + f of the whole state
                // (both bodies' free dofs, the multipliers), accelerated by
                // Anderson mixing: the frozen tangent leaves one slow mode (the
                // contact's sliding along the rotating indenter surface), which
                // the mixing removes. The history restarts when the contact set changes.
                let mut x = self.gel.free_values();
                x.extend(self.indenter.free_values());
                x.extend(self.lambda.iter().copied());
                let mut f = dg;
                f.extend(di);
                f.extend((0..ns).map(|k| if active[k] { dlam[k] } else { -self.lambda[k] }));
                if active != last_active {
                    history.clear();
                    last_active = active.clone();
                }
                let next = anderson(&mut history, &x, &f);
                let (ng, rest) = next.split_at(self.gel.free);
                let (ni, nl) = rest.split_at(self.indenter.free);
                self.gel.set_free_values(ng);
                self.indenter.set_free_values(ni);
                for k in 0..ns {
                    self.lambda[k] = if active[k] { nl[k].max(0.0) } else { 0.0 };
                }
                // A node sliding over a corner of the indenter's chain can hold the
                // iteration at a few hundredths of a micrometre: after a few fresh
                // tangents that is accepted.
                if size < TOLERANCE_MM
                    || (round >= STALL_ROUNDS && size < STALL_TOLERANCE_MM)
                    || (round >= LATE_ROUNDS && size < LATE_TOLERANCE_MM)
                {
                    return Ok(self.state());
                }
                prev = prev.min(size);
                // A fresh tangent when the mixed iteration stalls.
                if history.len() >= ANDERSON_DEPTH && size > 0.3 * prev {
                    break;
                }
            }
        }
        Err(FemError::ContactNotSettled(total))
    }

    /// The multipliers' change for one iteration and the contact set: the
    /// condensed constraints (frozen rows and columns) on the nodes in contact,
    /// with the nodes pulling let go one at a time and the nodes passing
    /// through taken in. `None` if the set does not settle.
    fn multipliers(
        &self,
        frozen: &Frozen,
        cols: &mut [Option<(Vec<f64>, Vec<f64>)>],
        proj: &[Projection],
        ag: &[f64],
        ai: &[f64],
        active: &mut [bool],
    ) -> Option<Vec<f64>> {
        let ns = self.slaves.len();
        let rows = frozen.rows;
        let dot = |row: &[(usize, f64)], v: &[f64]| row.iter().map(|&(d, c)| c * v[d]).sum::<f64>();
        for _ in 0..4 * ns + 10 {
            let idx: Vec<usize> = (0..ns).filter(|&k| active[k]).collect();
            // Nodes let go drop their whole multiplier.
            let gone: Vec<usize> = (0..ns).filter(|&k| !active[k] && self.lambda[k] != 0.0).collect();
            // The constraints' columns not yet known, solved together.
            let missing: Vec<usize> = idx.iter().chain(&gone).copied().filter(|&k| cols[k].is_none()).collect();
            if !missing.is_empty() {
                let load = |row: &Row, len: usize| {
                    let mut e = vec![0.0; len];
                    row.iter().for_each(|&(d, c)| e[d] += c);
                    e
                };
                let eg: Vec<Vec<f64>> = missing.iter().map(|&k| load(&rows[k].0, self.gel.free)).collect();
                let ei: Vec<Vec<f64>> = missing.iter().map(|&k| load(&rows[k].1, self.indenter.free)).collect();
                let solved = frozen.kg.solve_many(&eg).into_iter().zip(frozen.ki.solve_many(&ei));
                for (&k, pair) in missing.iter().zip(solved) {
                    cols[k] = Some(pair);
                }
            }
            let coupling = |k: usize, l: usize| match &cols[l] {
                Some((cg, ci)) => dot(&rows[k].0, cg) + dot(&rows[k].1, ci),
                None => 0.0,
            };
            let lin_gap = |k: usize, dl: &[f64]| {
                proj[k].gap + dot(&rows[k].0, ag) - dot(&rows[k].1, ai)
                    + (0..ns).filter(|&l| dl[l] != 0.0).map(|l| coupling(k, l) * dl[l]).sum::<f64>()
            };
            let mut known = vec![0.0; ns];
            gone.iter().for_each(|&k| known[k] = -self.lambda[k]);
            let a: Vec<Vec<f64>> = idx.iter().map(|&k| idx.iter().map(|&l| coupling(k, l)).collect()).collect();
            let b: Vec<f64> = idx.iter().map(|&k| -lin_gap(k, &known)).collect();
            let x = if idx.is_empty() { Vec::new() } else { dense::solve(a, b)? };
            let mut dlam = known;
            for (m, &k) in idx.iter().enumerate() {
                dlam[k] = x[m];
            }
            let pulling = idx.iter().copied().filter(|&k| self.lambda[k] + dlam[k] < 0.0);
            if let Some(worst) =
                pulling.min_by(|&a, &b| (self.lambda[a] + dlam[a]).total_cmp(&(self.lambda[b] + dlam[b])))
            {
                active[worst] = false;
                continue;
            }
            let entering: Vec<usize> = (0..ns).filter(|&k| !active[k] && lin_gap(k, &dlam) < -1e-12).collect();
            if entering.is_empty() {
                return Some(dlam);
            }
            entering.iter().for_each(|&k| active[k] = true);
        }
        None
    }

    fn state(&self) -> LargeState {
        let ns = self.slaves.len();
        let mut meets = vec![None; ns];
        let mut force = 0.0;
        let mut last = 0;
        let surface = self.chain_surface();
        for k in 0..ns {
            if self.lambda[k] > 0.0 {
                let pr = self.project_on(&surface, self.slaves[k]);
                meets[k] = Some((pr.m, pr.xi));
                force += self.lambda[k] * -pr.normal[1];
                last = k;
            }
        }
        let gamma1 = -self.gel.u[self.slaves[0]][1];
        LargeState {
            delta_mm: self.delta_mm,
            force_n: 2.0 * PI * force,
            gamma1_mm: gamma1,
            gamma2_mm: self.delta_mm - gamma1,
            contact_radius_mm: self.gel.x(self.slaves[last])[0],
            nodal_force: self.lambda.clone(),
            radius_mm: self.slaves.iter().map(|&s| self.gel.x(s)[0]).collect(),
            meets,
        }
    }

    /// The contact along a monotone approach through every entry of `deltas_mm`
    /// (increasing), in load steps of at most `max_step_mm`.
    /// [`Self::step_to`]; a step whose iteration does not settle is taken again
    /// from where it started in two halves (at most `depth` times over): the
    /// iteration's trouble spots (a node on a corner of the indenter's chain)
    /// depend on where the load steps fall.
    fn step_or_split(&mut self, delta_mm: f64, depth: usize) -> Result<LargeState, FemError> {
        let saved = (self.gel.u.clone(), self.indenter.u.clone(), self.lambda.clone(), self.delta_mm);
        match self.step_to(delta_mm) {
            Err(FemError::ContactNotSettled(n)) => {
                if depth == 0 {
                    return Err(FemError::ContactNotSettled(n));
                }
                (self.gel.u, self.indenter.u, self.lambda, self.delta_mm) = saved;
                let mid = 0.5 * (self.delta_mm + delta_mm);
                self.step_or_split(mid, depth - 1)?;
                self.step_or_split(delta_mm, depth - 1)
            }
            other => other,
        }
    }

    pub fn solve_path(&mut self, deltas_mm: &[f64], max_step_mm: f64) -> Result<Vec<LargeState>, FemError> {
        let mut out = Vec::with_capacity(deltas_mm.len());
        for &target in deltas_mm {
            if target.is_nan() || target < self.delta_mm || max_step_mm.is_nan() || max_step_mm <= 0.0 {
                return Err(FemError::Invalid(format!("approach {target} mm after {} mm", self.delta_mm)));
            }
            let steps = ((target - self.delta_mm) / max_step_mm).ceil().max(1.0) as usize;
            let from = self.delta_mm;
            let mut st = None;
            for m in 1..=steps {
                st = Some(self.step_or_split(from + (target - from) * m as f64 / steps as f64, 3)?);
            }
            out.push(st.unwrap_or_else(|| self.state()));
        }
        Ok(out)
    }
}

/// Anderson mixing depth.
const ANDERSON_DEPTH: usize = 6;

/// One Anderson (type II) update of the fixed-point iteration x -> x + f, with
/// the last few (x, f) pairs in `history`; returns the next x.
fn anderson(history: &mut Vec<(Vec<f64>, Vec<f64>)>, x: &[f64], f: &[f64]) -> Vec<f64> {
    history.push((x.to_vec(), f.to_vec()));
    if history.len() > ANDERSON_DEPTH + 1 {
        history.remove(0);
    }
    let m = history.len() - 1;
    let plain = || x.iter().zip(f).map(|(a, b)| a + b).collect::<Vec<f64>>();
    if m == 0 {
        return plain();
    }
    // Differences to the newest pair.
    let df: Vec<Vec<f64>> = (0..m).map(|j| f.iter().zip(&history[j].1).map(|(a, b)| a - b).collect()).collect();
    let dx: Vec<Vec<f64>> = (0..m).map(|j| x.iter().zip(&history[j].0).map(|(a, b)| a - b).collect()).collect();
    let dotv = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| p * q).sum::<f64>();
    let mut a: Vec<Vec<f64>> = (0..m).map(|i| (0..m).map(|j| dotv(&df[i], &df[j])).collect()).collect();
    let scale = (0..m).map(|i| a[i][i]).fold(0.0f64, f64::max);
    (0..m).for_each(|i| a[i][i] += 1e-12 * scale + 1e-300);
    let b: Vec<f64> = (0..m).map(|i| dotv(&df[i], f)).collect();
    let Some(gamma) = dense::solve(a, b) else {
        history.clear();
        return plain();
    };
    let mut out = plain();
    for j in 0..m {
        for (k, o) in out.iter_mut().enumerate() {
            *o -= gamma[j] * (dx[j][k] + df[j][k]);
        }
    }
    out
}
