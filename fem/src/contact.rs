//! Frictionless contact of the indenter with the gel, condensed onto the shared
//! contact-surface nodes: each body is its surface compliance matrix (linear
//! elasticity), and the contact is the linear complementarity problem
//!   (G_gel + G_ind) P = δ - f(r) on the nodes in contact, P >= 0,
//!   no node outside passes through the other body,
//! solved by an active set. f is the exact sphere's profile; gaps are vertical
//! (small strain, small sliding).

use std::collections::HashMap;
use std::f64::consts::PI;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::FemError;
use crate::dense::{self, PrefixCholesky};
use crate::elastic::{Body, SurfaceCompliance};

/// How far the interpolated edge of a node-to-node contact runs ahead of the
/// true edge, in node spacings ([`TwoBodyContact::contact_radius_mm`]):
/// measured against the analytical layer solution, 0.30-0.35 at nu 0.3 and
/// at shallow depths at nu 0.48.
const EDGE_LEAD: f64 = 0.31;

/// One solved contact.
#[derive(Debug, Clone, PartialEq)]
pub struct ContactState {
    /// Platform approach since first touch, mm.
    pub delta_mm: f64,
    /// Total force, N.
    pub force_n: f64,
    /// The gel's surface deflection on the axis, mm.
    pub gamma1_mm: f64,
    /// The indenter's deformation (delta - gamma1), mm.
    pub gamma2_mm: f64,
    /// Radius of the outermost node in contact and of the next node out, mm.
    pub contact_radius_mm: [f64; 2],
    /// Nodal forces per radian at the surface nodes, N/rad.
    pub nodal_force: Vec<f64>,
    /// Radial friction forces per radian on the gel's surface nodes (outward
    /// positive), N/rad; zero in frictionless contact.
    pub nodal_shear: Vec<f64>,
}

/// The gel and the indenter (rigid when `None`), condensed onto their common surface nodes.
pub struct TwoBodyContact {
    radius_mm: f64,
    r: Vec<f64>,
    g_gel: Vec<Vec<f64>>,
    g_sum: Vec<Vec<f64>>,
    /// Cholesky factor of `g_sum`: the contact on the first k nodes at O(k²);
    /// factored as far as a contact has reached (a sweep's contact stays well
    /// inside the nodes an indenter could touch).
    factor: Mutex<Leading>,
    /// Nodes in contact at the last solve: where the next one starts looking
    /// (a sweep's depths come in order).
    /// and how many nodes overlapped then (the disc's share of the overlap
    /// changes slowly with depth), packed as `nodes << 32 | overlap`.
    last_disc: AtomicU64,
}

/// A solved contact on surface nodes at radii `r`: `last` is the outermost
/// node in contact, the forces are per radian.
fn solved(
    delta_mm: f64,
    gamma1_mm: f64,
    r: &[f64],
    last: usize,
    nodal_force: Vec<f64>,
    nodal_shear: Vec<f64>,
) -> ContactState {
    ContactState {
        delta_mm,
        force_n: 2.0 * PI * nodal_force.iter().sum::<f64>(),
        gamma1_mm,
        gamma2_mm: delta_mm - gamma1_mm,
        contact_radius_mm: [r[last], r.get(last + 1).copied().unwrap_or(r[last])],
        nodal_force,
        nodal_shear,
    }
}

/// How far each node at radii `r_mm` must close at platform approach
/// `delta_mm`: the approach less the exact sphere's height above its tip there.
fn approach_needed(delta_mm: f64, sphere_radius_mm: f64, r_mm: &[f64]) -> Vec<f64> {
    r_mm.iter().map(|&r| delta_mm - sphere_height(sphere_radius_mm, r)).collect()
}

/// The exact sphere's height above its tip at radius `r_mm`.
fn sphere_height(sphere_radius_mm: f64, r_mm: f64) -> f64 {
    let big = sphere_radius_mm;
    big - (big * big - r_mm * r_mm).max(0.0).sqrt()
}

/// The frictionless contact's factor of the combined compliance and the
/// forward substitutions of the two parts of every gap (ones, times the
/// approach, and the sphere's heights), grown together as a contact reaches
/// further nodes.
#[derive(Default)]
struct Leading {
    factor: PrefixCholesky,
    ones: Vec<f64>,
    heights: Vec<f64>,
}

impl TwoBodyContact {
    /// `indenter_radius_mm` is the sphere's radius (its profile in the gap).
    /// With an elastic indenter, its surface radii must be the gel's first ones.
    pub fn new(gel: &Body, indenter: Option<&Body>, indenter_radius_mm: f64) -> Result<Self, FemError> {
        let r_gel = gel.mesh.surface_radii();
        let g_gel_full = gel.surface_compliance();
        let (n, g_ind) = match indenter {
            Some(b) => {
                let r_ind = b.mesh.surface_radii();
                if r_ind.len() > r_gel.len() || r_ind.iter().zip(&r_gel).any(|(a, b)| (a - b).abs() > 1e-9) {
                    return Err(FemError::Invalid("the indenter's surface nodes must sit at the gel's radii".into()));
                }
                (r_ind.len(), Some(b.surface_compliance()))
            }
            None => (r_gel.iter().take_while(|&&r| r < 0.99 * indenter_radius_mm).count(), None),
        };
        let g_gel: Vec<Vec<f64>> = (0..n).map(|j| g_gel_full[j][..n].to_vec()).collect();
        let g_sum =
            (0..n).map(|j| (0..n).map(|i| g_gel[j][i] + g_ind.as_ref().map_or(0.0, |g| g[j][i])).collect()).collect();
        Ok(Self::assemble(indenter_radius_mm, r_gel[..n].to_vec(), g_gel, g_sum))
    }

    fn assemble(radius_mm: f64, r: Vec<f64>, g_gel: Vec<Vec<f64>>, g_sum: Vec<Vec<f64>>) -> Self {
        Self { radius_mm, r, g_gel, g_sum, factor: Mutex::new(Leading::default()), last_disc: AtomicU64::new(0) }
    }

    /// From compliance matrices already on common surface nodes at radii `r`
    /// (column-major: `g[j][i]` is node i's response to a load on node j).
    pub fn from_compliances(r: Vec<f64>, g_gel: Vec<Vec<f64>>, g_ind: &[Vec<f64>], indenter_radius_mm: f64) -> Self {
        let n = r.len();
        let g_sum = g_gel[..n]
            .iter()
            .zip(&g_ind[..n])
            .map(|(g, i)| g[..n].iter().zip(&i[..n]).map(|(a, b)| a + b).collect())
            .collect();
        Self::assemble(indenter_radius_mm, r, g_gel, g_sum)
    }

    pub fn radii(&self) -> &[f64] {
        &self.r
    }

    /// The combined compliance's factor and forward substitutions, grown to
    /// the first `k` nodes; `None` when the factor cannot reach them.
    fn leading(&self, k: usize) -> Option<std::sync::MutexGuard<'_, Leading>> {
        let mut l = crate::lock_cache(&self.factor);
        if l.factor.extend_to(k, |i, j| self.g_sum[j][i]) < k {
            return None;
        }
        let Leading { factor, ones, heights } = &mut *l;
        factor.forward_extend(ones, k, |_| 1.0);
        factor.forward_extend(heights, k, |i| sphere_height(self.radius_mm, self.r[i]));
        Some(l)
    }

    /// The contact's edge in `st`, between its outermost node in contact and
    /// the next one out, continuous in the approach (the outermost node jumps by
    /// a mesh spacing as nodes touch down). With the nodes in contact held, the
    /// forces and gaps are linear in the approach: the outermost node's force
    /// came from zero at δ_in and the next node's gap closes at δ_out, and the
    /// edge moves linearly from the one node to the other between them
    /// (docs/physics.md, "Finite-element reference"). Radial friction forces
    /// are left out of the gap: they move it by far less than the mesh spacing.
    pub fn contact_edge_mm(&self, st: &ContactState) -> f64 {
        let r = &self.r;
        let Some(last) = (0..r.len()).rev().find(|&i| st.nodal_force[i] > 0.0) else {
            return 0.0;
        };
        let next = last + 1;
        if next >= r.len() {
            return r[last];
        }
        // Forces per unit approach with this disc in contact.
        let Some(x) = self.leading(next).and_then(|l| l.factor.backward(l.ones[..next].to_vec())) else {
            return r[last];
        };
        let delta = st.delta_mm;
        let need = approach_needed(delta, self.radius_mm, &r[next..=next])[0];
        let gap = (0..next).map(|j| self.g_sum[j][next] * st.nodal_force[j]).sum::<f64>() - need;
        let closing = 1.0 - (0..next).map(|j| self.g_sum[j][next] * x[j]).sum::<f64>();
        let (rising, p_last) = (x[last], st.nodal_force[last]);
        if !(rising > 0.0 && closing > 0.0) {
            return r[last];
        }
        let (d_in, d_out) = (delta - p_last / rising, delta + gap.max(0.0) / closing);
        let f = if d_out > d_in { ((delta - d_in) / (d_out - d_in)).clamp(0.0, 1.0) } else { 1.0 };
        r[last] + f * (r[next] - r[last])
    }

    /// The contact's radius in `st`: [`Self::contact_edge_mm`] moved in by
    /// the lead a node-to-node contact has on the true edge. A node just
    /// outside the edge already carries force from the pressure inside its
    /// span, so the interpolated edge runs ahead of the exact one by about a
    /// third of the node spacing at every depth; on a rigid sphere pressing
    /// the bonded layer its radius lies 17-21 µm outside the analytical
    /// layer solution's on the 0.06 mm mesh, and this within 1 µm (nu 0.3)
    /// and 7 µm (nu 0.48; `fem/tests/reference.rs`,
    /// `the_contact_radius_is_the_analytical_layers`).
    pub fn contact_radius_mm(&self, st: &ContactState) -> f64 {
        let edge = self.contact_edge_mm(st);
        let r = &self.r;
        match (0..r.len()).rev().find(|&i| st.nodal_force[i] > 0.0) {
            Some(last) if last + 1 < r.len() => edge - EDGE_LEAD * (r[last + 1] - r[last]),
            _ => edge,
        }
    }

    /// The contact at platform approach `delta_mm`.
    pub fn solve(&self, delta_mm: f64) -> Result<ContactState, FemError> {
        let need = approach_needed(delta_mm, self.radius_mm, &self.r);
        match self.solve_disc(delta_mm, &need) {
            Some(st) => Ok(st),
            None => self.solve_active_set(delta_mm, need),
        }
    }

    /// The contact as a disc of the first k nodes (what a frictionless
    /// axisymmetric contact is): k is walked from a Hertz-like guess until the
    /// forces inside are compressive and no node outside passes through, each
    /// try one solve on the factor's leading block. `None` when no disc
    /// satisfies both, for the general active set to decide.
    fn solve_disc(&self, delta_mm: f64, need: &[f64]) -> Option<ContactState> {
        let n = self.r.len();
        let overlap = need.iter().take_while(|&&d| d > 0.0).count();
        let most = overlap;
        if most == 0 {
            return None;
        }
        // Elastic contact reaches about 1/sqrt(2) of the overlap's radius (Hertz),
        // unless the last solve knows better.
        let hertz = (overlap as f64) * std::f64::consts::FRAC_1_SQRT_2;
        let last = self.last_disc.load(Ordering::Relaxed);
        let (last_k, last_overlap) = ((last >> 32) as f64, (last & u64::from(u32::MAX)) as f64);
        let guess = if last_k > 0.0 && last_overlap > 0.0 { last_k * overlap as f64 / last_overlap } else { hertz };
        let mut k = guess.round().clamp(1.0, most as f64) as usize;
        let tol = 1e-12 * delta_mm.abs().max(1e-9);
        let mut came_from = 0i8;
        for _ in 0..=n {
            // The gap to close is the approach less the sphere's height: its
            // forward substitution is the approach times that of ones less
            // that of the heights, both kept with the factor.
            let p = {
                let l = self.leading(k)?;
                let y: Vec<f64> = l.ones[..k].iter().zip(&l.heights[..k]).map(|(o, h)| delta_mm * o - h).collect();
                l.factor.backward(y)?
            };
            if p.iter().any(|&v| v < 0.0) {
                if came_from == 1 || k == 1 {
                    return None;
                }
                came_from = -1;
                k -= 1;
                continue;
            }
            // The closure of the nodes outside, column by column (contiguous).
            let mut w = vec![0.0; n - k];
            for (j, &pj) in p.iter().enumerate() {
                w.iter_mut().zip(&self.g_sum[j][k..]).for_each(|(wi, g)| *wi += g * pj);
            }
            let enters = need[k..].iter().zip(&w).any(|(&d, &wi)| d > wi + tol);
            if enters {
                if came_from == -1 || k == most {
                    return None;
                }
                came_from = 1;
                k += 1;
                continue;
            }
            self.last_disc.store(((k as u64) << 32) | overlap as u64, Ordering::Relaxed);
            let mut nodal_force = p;
            nodal_force.resize(n, 0.0);
            return Some(self.state(delta_mm, nodal_force, k - 1));
        }
        None
    }

    /// The solved contact from its nodal forces; `last` is the outermost node in contact.
    fn state(&self, delta_mm: f64, nodal_force: Vec<f64>, last: usize) -> ContactState {
        let gamma1: f64 = nodal_force.iter().zip(&self.g_gel).map(|(p, col)| col[0] * p).sum();
        let shear = vec![0.0; nodal_force.len()];
        solved(delta_mm, gamma1, &self.r, last, nodal_force, shear)
    }

    /// The general active set (any set of nodes in contact).
    fn solve_active_set(&self, delta_mm: f64, need: Vec<f64>) -> Result<ContactState, FemError> {
        let n = self.r.len();
        let mut active: Vec<bool> = need.iter().map(|&d| d > 0.0).collect();
        let mut p = vec![0.0; n];
        let mut passes_releasing = 0;
        for _ in 0..4 * n + 10 {
            let idx: Vec<usize> = (0..n).filter(|&i| active[i]).collect();
            let a: Vec<Vec<f64>> = idx.iter().map(|&i| idx.iter().map(|&j| self.g_sum[j][i]).collect()).collect();
            let b: Vec<f64> = idx.iter().map(|&i| need[i]).collect();
            let x =
                if idx.is_empty() { Vec::new() } else { dense::solve(a, b).ok_or(FemError::NotPositiveDefinite(0))? };
            p.iter_mut().for_each(|v| *v = 0.0);
            for (k, &i) in idx.iter().enumerate() {
                p[i] = x[k];
            }
            // Pulling nodes let go: all at once while that converges, then the most
            // negative one at a time.
            let pulling: Vec<usize> = idx.iter().copied().filter(|&i| p[i] < 0.0).collect();
            if !pulling.is_empty() {
                passes_releasing += 1;
                if passes_releasing <= 8 {
                    pulling.iter().for_each(|&i| active[i] = false);
                } else if let Some(&worst) = pulling.iter().min_by(|&&a, &&b| p[a].total_cmp(&p[b])) {
                    active[worst] = false;
                }
                continue;
            }
            // A free node that would pass through the indenter touches.
            let w: Vec<f64> = (0..n).map(|i| (0..n).map(|j| self.g_sum[j][i] * p[j]).sum()).collect();
            let tol = 1e-12 * delta_mm.abs().max(1e-9);
            let entering: Vec<usize> = (0..n).filter(|&i| !active[i] && need[i] > w[i] + tol).collect();
            if entering.is_empty() {
                let last = (0..n).rev().find(|&i| active[i]).unwrap_or(0);
                return Ok(self.state(delta_mm, p, last));
            }
            for i in entering {
                active[i] = true;
            }
        }
        Err(FemError::ContactNotSettled(4 * n + 10))
    }
}

/// The stuck core of a frictional path: its factor, grown with the contact,
/// and the core's response to each unknown outside it, per core size (the
/// same column of the same compliance, met again at every pass of every load
/// step while the core keeps its size: solved once).
struct StuckCore {
    factor: PrefixCholesky,
    responses: HashMap<(usize, Unknown), Vec<f64>>,
    /// L⁻¹ of the core's right-hand side in the current load step, as far as
    /// a pass has needed it: the core's rows close their gaps and hold their
    /// slips, which change only from one step to the next, so every pass of a
    /// step shares one forward substitution (emptied when a step starts).
    rhs_forward: Vec<f64>,
}

/// An unknown of the frictional contact: a node's normal force or its radial friction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
enum Unknown {
    P(usize),
    Q(usize),
}

impl Unknown {
    fn node(self) -> usize {
        match self {
            Unknown::P(i) | Unknown::Q(i) => i,
        }
    }
}

/// The k-th unknown in node order: p0, p1, q1, p2, q2, ... (the axis node
/// carries no radial friction).
/// The state a frictional path carries from one load step to the next.
struct PathState<'a> {
    status: &'a mut [Node],
    p: &'a mut [f64],
    q: &'a mut [f64],
    s_ref: &'a mut [f64],
}

/// How many times over a load step that does not settle is halved.
const STEP_SPLITS: usize = 3;

fn interleaved(k: usize) -> Unknown {
    match k {
        0 => Unknown::P(0),
        _ if k % 2 == 1 => Unknown::P(k.div_ceil(2)),
        _ => Unknown::Q(k / 2),
    }
}

/// A node's state in frictional contact.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Node {
    Free,
    Stick,
    /// Slipping; the friction force on the gel is `-mu p d` (d = direction of the
    /// gel's slip relative to the indenter, +1 outward).
    Slip(f64),
}

/// Normal contact with Coulomb friction between the indenter and the gel
/// (docs/physics.md, "Finite-element reference"). Each body is its surface
/// compliance in (r, z); on the nodes in contact the gap is closed, and each
/// node either sticks (its relative radial displacement keeps the value it had
/// at the previous load step) or slips with |q| = mu p against the slip. Friction
/// makes the answer depend on the path, so the contact is followed through the
/// approach in steps.
pub struct FrictionalContact {
    radius_mm: f64,
    r: Vec<f64>,
    gel: SurfaceCompliance,
    sum: SurfaceCompliance,
    /// The stuck core's factor as far as a path has grown it: the next path
    /// starts from it (a fit follows several paths on one model).
    stuck: Mutex<PrefixCholesky>,
}

impl FrictionalContact {
    /// Both bodies on common surface nodes at radii `r` (the gel's first nodes).
    pub fn new(r: Vec<f64>, gel: SurfaceCompliance, indenter: &SurfaceCompliance, indenter_radius_mm: f64) -> Self {
        let n = r.len();
        let add = |a: &Vec<Vec<f64>>, b: &Vec<Vec<f64>>| -> Vec<Vec<f64>> {
            (0..n).map(|j| (0..n).map(|i| a[j][i] + b[j][i]).collect()).collect()
        };
        let sum = SurfaceCompliance {
            rr: add(&gel.rr, &indenter.rr),
            rz: add(&gel.rz, &indenter.rz),
            zr: add(&gel.zr, &indenter.zr),
            zz: add(&gel.zz, &indenter.zz),
        };
        Self { radius_mm: indenter_radius_mm, r, gel, sum, stuck: Mutex::new(PrefixCholesky::empty()) }
    }

    /// Gap closure and relative radial slip at every node for normal forces `p`
    /// and friction forces `q` on the gel: (gap + delta - f(r), slip). The
    /// first `stuck` nodes are a stuck core (in contact, sticking): their gap
    /// is closed and their slip is `s_ref` by the equations just solved, and
    /// nothing reads their gap, so only the nodes beyond are computed (the
    /// core's gap is left at zero).
    fn kinematics(&self, p: &[f64], q: &[f64], stuck: usize, s_ref: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let n = self.r.len();
        let mut w = vec![0.0; n];
        let mut s = vec![0.0; n];
        s[..stuck].copy_from_slice(&s_ref[..stuck]);
        let (wo, so) = (&mut w[stuck..], &mut s[stuck..]);
        for j in 0..n {
            if p[j] == 0.0 && q[j] == 0.0 {
                continue;
            }
            let (zz, zr) = (&self.sum.zz[j][stuck..], &self.sum.zr[j][stuck..]);
            let (rr, rz) = (&self.sum.rr[j][stuck..], &self.sum.rz[j][stuck..]);
            for i in 0..n - stuck {
                wo[i] += zz[i] * p[j] - zr[i] * q[j];
                so[i] += rr[i] * q[j] - rz[i] * p[j];
            }
        }
        (w, s)
    }

    /// The contact along a monotone approach through every positive value of
    /// `deltas_mm` (any order; a state per entry, zero load at or below 0), in
    /// steps of at most `max_step_mm`. `mu = 0` is frictionless, `mu = inf` sticks.
    pub fn solve_path(&self, deltas_mm: &[f64], mu: f64, max_step_mm: f64) -> Result<Vec<ContactState>, FemError> {
        if mu.is_nan() || mu < 0.0 || max_step_mm.is_nan() || max_step_mm <= 0.0 {
            return Err(FemError::Invalid(format!("friction {mu}, load step {max_step_mm} mm")));
        }
        let n = self.r.len();
        let mut order: Vec<usize> = (0..deltas_mm.len()).collect();
        order.sort_by(|&a, &b| deltas_mm[a].total_cmp(&deltas_mm[b]));
        let mut out: Vec<Option<ContactState>> = vec![None; deltas_mm.len()];
        let mut status = vec![Node::Free; n];
        let mut p = vec![0.0; n];
        let mut q = vec![0.0; n];
        let mut s_ref = vec![0.0; n];
        // The stuck contact's factor, grown with the contact along the path
        // (a copy: paths of one model may run at once).
        let factor = crate::lock_cache(&self.stuck).clone();
        let mut stuck = StuckCore { factor, responses: HashMap::new(), rhs_forward: Vec::new() };
        let mut at = 0.0f64;
        for &k in &order {
            let target = deltas_mm[k];
            if !target.is_finite() {
                return Err(FemError::Invalid(format!("approach {target} mm")));
            }
            if target > at {
                let steps = ((target - at) / max_step_mm).ceil().max(1.0) as usize;
                let from = at;
                for m in 1..=steps {
                    let delta = from + (target - from) * m as f64 / steps as f64;
                    let before = from + (target - from) * (m - 1) as f64 / steps as f64;
                    let mut st = PathState { status: &mut status, p: &mut p, q: &mut q, s_ref: &mut s_ref };
                    self.step_or_split(before, delta, mu, &mut st, &mut stuck, STEP_SPLITS)?;
                }
                at = target;
            }
            out[k] = Some(if target <= 0.0 {
                self.state(target, &vec![0.0; n], &vec![0.0; n])
            } else {
                self.state(target, &p, &q)
            });
        }
        let mut shared = crate::lock_cache(&self.stuck);
        if stuck.factor.len() > shared.len() {
            *shared = stuck.factor;
        }
        drop(shared);
        out.into_iter()
            .map(|s| s.ok_or_else(|| FemError::Invalid("an approach of the path was not solved".into())))
            .collect()
    }

    fn state(&self, delta_mm: f64, p: &[f64], q: &[f64]) -> ContactState {
        let n = self.r.len();
        let gamma1: f64 = (0..n).map(|j| self.gel.zz[j][0] * p[j] - self.gel.zr[j][0] * q[j]).sum();
        let last = (0..n).rev().find(|&i| p[i] > 0.0).unwrap_or(0);
        solved(delta_mm, gamma1, &self.r, last, p.to_vec(), q.to_vec())
    }

    /// The coefficient of unknown `col` in the equation of unknown `row` when
    /// the node of a friction unknown sticks: a normal force's row closes its
    /// node's gap, a friction force's row holds its node's relative radial
    /// displacement. In the interleaved order ([`interleaved`]) these are the
    /// combined compliance of both bodies with the friction's sign turned, so
    /// symmetric positive definite, and a stuck disc of nodes is its leading
    /// block.
    fn stick_coef(&self, row: Unknown, col: Unknown) -> f64 {
        match (row, col) {
            (Unknown::P(i), Unknown::P(j)) => self.sum.zz[j][i],
            (Unknown::P(i), Unknown::Q(j)) => -self.sum.zr[j][i],
            (Unknown::Q(i), Unknown::P(j)) => -self.sum.rz[j][i],
            (Unknown::Q(i), Unknown::Q(j)) => self.sum.rr[j][i],
        }
    }

    /// The coefficient of `col` in `row`'s equation under the nodes' `status`: a
    /// slipping node's friction row is q + mu d p = 0 instead.
    fn coef(&self, row: Unknown, col: Unknown, status: &[Node], mu: f64) -> f64 {
        match (row, status[row.node()]) {
            (Unknown::Q(i), Node::Slip(d)) => match col {
                Unknown::Q(j) if j == i => 1.0,
                Unknown::P(j) if j == i && d != 0.0 => mu * d,
                _ => 0.0,
            },
            _ => self.stick_coef(row, col),
        }
    }

    /// The right-hand side of `row`'s equation (see [`Self::coef`]).
    fn rhs(row: Unknown, need: &[f64], status: &[Node], s_ref: &[f64]) -> f64 {
        match (row, status[row.node()]) {
            (Unknown::P(i), _) => need[i],
            (Unknown::Q(_), Node::Slip(_)) => 0.0,
            (Unknown::Q(i), _) => s_ref[i],
        }
    }

    /// The forces of the current active set: normal forces `p` on the nodes in
    /// contact (closing them by `need`), friction `q` on those off the axis
    /// (sticking ones keep their slip `s_ref`, slipping ones carry mu p).
    /// Returns the nodes in contact.
    ///
    /// A contact sticks over a core from the axis out, with at most a few
    /// nodes outside it slipping or touching down: the core is a leading block
    /// of `stuck` (the interleaved factor, grown as the contact grows and kept
    /// along the path), and the rest is its Schur complement, a small dense
    /// system. Anything else, or a factor that cannot reach the core, is
    /// eliminated as a whole.
    #[allow(clippy::too_many_arguments)]
    fn solve_active_set(
        &self,
        need: &[f64],
        mu: f64,
        status: &[Node],
        s_ref: &[f64],
        stuck: &mut StuckCore,
        p: &mut [f64],
        q: &mut [f64],
    ) -> Result<Vec<usize>, FemError> {
        let (unknowns, x) = self.solve_system(need, mu, status, s_ref, Some(stuck))?;
        p.iter_mut().for_each(|v| *v = 0.0);
        q.iter_mut().for_each(|v| *v = 0.0);
        for (u, v) in unknowns.into_iter().zip(x) {
            match u {
                Unknown::P(i) => p[i] = v,
                Unknown::Q(i) => q[i] = v,
            }
        }
        Ok((0..self.r.len()).filter(|&i| status[i] != Node::Free).collect())
    }

    /// The active set's unknowns and their values: on the stuck core's factor
    /// and the Schur complement of the rest when `stuck` is given (and reaches
    /// the core), else by elimination of the whole system.
    fn solve_system(
        &self,
        need: &[f64],
        mu: f64,
        status: &[Node],
        s_ref: &[f64],
        stuck: Option<&mut StuckCore>,
    ) -> Result<(Vec<Unknown>, Vec<f64>), FemError> {
        let n = self.r.len();
        // The stuck core: nodes 0..c all in contact, sticking off the axis.
        let c = (0..n).take_while(|&i| status[i] != Node::Free && (i == 0 || status[i] == Node::Stick)).count();
        let nc = (2 * c).saturating_sub(1);
        let core: Vec<Unknown> = (0..nc).map(interleaved).collect();
        let extra: Vec<Unknown> = (c..n)
            .filter(|&i| status[i] != Node::Free)
            .flat_map(|i| std::iter::once(Unknown::P(i)).chain((i > 0).then_some(Unknown::Q(i))))
            .collect();
        let rhs = |u: Unknown| Self::rhs(u, need, status, s_ref);
        // The block form pays when the core is most of the system.
        let blocks = nc > 0 && extra.len() <= nc;
        let stuck = stuck.filter(|_| blocks).and_then(|f| {
            (f.factor.extend_to(nc, |a, b| self.stick_coef(interleaved(a), interleaved(b))) >= nc).then_some(f)
        });
        let Some(stuck) = stuck else {
            let unknowns: Vec<Unknown> = core.into_iter().chain(extra).collect();
            let a: Vec<Vec<f64>> =
                unknowns.iter().map(|&r| unknowns.iter().map(|&u| self.coef(r, u, status, mu)).collect()).collect();
            let b: Vec<f64> = unknowns.iter().map(|&u| rhs(u)).collect();
            let x = if unknowns.is_empty() {
                Vec::new()
            } else {
                dense::solve(a, b).ok_or(FemError::NotPositiveDefinite(0))?
            };
            return Ok((unknowns, x));
        };
        stuck.factor.forward_extend(&mut stuck.rhs_forward, nc, |k| rhs(core[k]));
        let z = stuck.factor.backward(stuck.rhs_forward[..nc].to_vec()).ok_or(FemError::NotPositiveDefinite(0))?;
        // The core's response to each unknown outside it.
        let ys: Vec<Vec<f64>> = extra
            .iter()
            .map(|&e| {
                if let Some(y) = stuck.responses.get(&(nc, e)) {
                    return Ok(y.clone());
                }
                let col: Vec<f64> = core.iter().map(|&r| self.stick_coef(r, e)).collect();
                let y = stuck.factor.solve_prefix(&col).ok_or(FemError::NotPositiveDefinite(0))?;
                stuck.responses.insert((nc, e), y.clone());
                Ok(y)
            })
            .collect::<Result<_, _>>()?;
        let ne = extra.len();
        let mut schur = vec![vec![0.0; ne]; ne];
        let mut g = vec![0.0; ne];
        for (a, &ea) in extra.iter().enumerate() {
            let row: Vec<f64> = core.iter().map(|&r| self.coef(ea, r, status, mu)).collect();
            let dot = |v: &[f64]| row.iter().zip(v).map(|(u, w)| u * w).sum::<f64>();
            g[a] = rhs(ea) - dot(&z);
            for (b, &eb) in extra.iter().enumerate() {
                schur[a][b] = self.coef(ea, eb, status, mu) - dot(&ys[b]);
            }
        }
        let xe = if ne == 0 { Vec::new() } else { dense::solve(schur, g).ok_or(FemError::NotPositiveDefinite(0))? };
        let mut x = z;
        for (y, &v) in ys.iter().zip(&xe) {
            x.iter_mut().zip(y).for_each(|(xi, yi)| *xi -= yi * v);
        }
        x.extend(xe);
        Ok((core.into_iter().chain(extra).collect(), x))
    }

    /// [`Self::step`] from approach `from` to `delta`; a step whose active set
    /// cycles without settling (a node changing between stick and slip at
    /// the contact's edge) is taken again from the same state in two halves,
    /// up to `splits` times over. Seen in a diagnosis of a dev-set recording
    /// cut to two twists (friction undetermined, fitted at 34): load steps of
    /// 0.03-0.04 mm near a 1 mm approach cycled, and settled in halves.
    fn step_or_split(
        &self,
        from: f64,
        delta: f64,
        mu: f64,
        st: &mut PathState<'_>,
        stuck: &mut StuckCore,
        splits: usize,
    ) -> Result<(), FemError> {
        let saved = (st.status.to_vec(), st.p.to_vec(), st.q.to_vec(), st.s_ref.to_vec());
        match self.step(delta, mu, st.status, st.p, st.q, st.s_ref, stuck) {
            Err(FemError::ContactNotSettled(n)) => {
                if splits == 0 {
                    return Err(FemError::ContactNotSettled(n));
                }
                st.status.copy_from_slice(&saved.0);
                st.p.copy_from_slice(&saved.1);
                st.q.copy_from_slice(&saved.2);
                st.s_ref.copy_from_slice(&saved.3);
                let mid = 0.5 * (from + delta);
                self.step_or_split(from, mid, mu, st, stuck, splits - 1)?;
                self.step_or_split(mid, delta, mu, st, stuck, splits - 1)
            }
            other => other,
        }
    }

    /// One load step to approach `delta`, from the converged state in the arguments.
    #[allow(clippy::too_many_arguments)]
    fn step(
        &self,
        delta: f64,
        mu: f64,
        status: &mut [Node],
        p: &mut [f64],
        q: &mut [f64],
        s_ref: &mut [f64],
        stuck: &mut StuckCore,
    ) -> Result<(), FemError> {
        let n = self.r.len();
        let need = approach_needed(delta, self.radius_mm, &self.r);
        let tol = 1e-12 * delta.abs().max(1e-9);
        let limit = 8 * n + 40;
        let mut releasing = 0;
        let mut passes = 0;
        stuck.rhs_forward.clear();
        let mut slid_free = vec![false; n];
        // Grip lost at the edge in the last step is regained.
        if mu > 0.0 {
            status.iter_mut().filter(|st| **st == Node::Slip(0.0)).for_each(|st| *st = Node::Stick);
        }
        for _ in 0..limit {
            let contact = self.solve_active_set(&need, mu, status, s_ref, stuck, p, q)?;
            // Pulling nodes let go (all at once while that converges, then the worst).
            let pulling: Vec<usize> = contact.iter().copied().filter(|&i| p[i] < 0.0).collect();
            if !pulling.is_empty() {
                releasing += 1;
                if releasing <= 8 {
                    pulling.iter().for_each(|&i| status[i] = Node::Free);
                } else if let Some(&worst) = pulling.iter().min_by(|&&a, &&b| p[a].total_cmp(&p[b])) {
                    status[worst] = Node::Free;
                }
                // A node that touches down and is then pulled off by its own grip
                // (the tensile edge of a stuck contact) comes back without friction
                // for the rest of this step.
                pulling.iter().for_each(|&i| slid_free[i] = true);
                continue;
            }
            let core = (0..n).take_while(|&i| status[i] != Node::Free && (i == 0 || status[i] == Node::Stick)).count();
            let (w, s) = self.kinematics(p, q, core, s_ref);
            // Every node that breaks its condition, with how far it breaks it.
            let mut wrong: Vec<(usize, Node, f64)> = Vec::new();
            for i in 0..n {
                match status[i] {
                    Node::Free => {
                        if need[i] > w[i] + tol {
                            // A node touching down sits at the edge, where the
                            // pressure is least: it enters slipping the way it moves.
                            let moving = s[i] - s_ref[i];
                            let to = if mu == 0.0 || slid_free[i] {
                                Node::Slip(0.0)
                            } else if i > 0 && moving != 0.0 && mu.is_finite() {
                                Node::Slip(moving.signum())
                            } else {
                                Node::Stick
                            };
                            wrong.push((i, to, (need[i] - w[i]) / delta.abs().max(1e-9)));
                        }
                    }
                    Node::Stick => {
                        if i > 0 && q[i].abs() > mu * p[i] * (1.0 + 1e-9) {
                            let excess = (q[i].abs() - mu * p[i]) / p[i].abs().max(1e-300);
                            wrong.push((i, Node::Slip(-q[i].signum()), excess));
                        }
                    }
                    Node::Slip(d) => {
                        let back = -d * (s[i] - s_ref[i]);
                        if mu > 0.0 && back > 1e-9 * (s[i].abs() + s_ref[i].abs()) + 1e-15 {
                            wrong.push((i, Node::Stick, back / delta.abs().max(1e-9)));
                        }
                    }
                }
            }
            let changed = !wrong.is_empty();
            passes += 1;
            if passes <= 12 {
                wrong.iter().for_each(|&(i, to, _)| status[i] = to);
            } else if let Some(&(i, to, _)) = wrong.iter().max_by(|a, b| a.2.total_cmp(&b.2)) {
                // Changing every wrong node at once can cycle: then one at a time.
                status[i] = to;
            }
            if !changed {
                s_ref.copy_from_slice(&s);
                return Ok(());
            }
        }
        Err(FemError::ContactNotSettled(limit))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::elastic::Material;
    use crate::mesh::Mesh;

    /// The frictional active set solved on the stuck core's factor and the
    /// Schur complement of the rest is the elimination of the whole system,
    /// for cores with slipping, stuck and missing nodes beyond them.
    #[test]
    fn the_stuck_core_and_its_complement_solve_as_elimination_does() {
        let gel_mesh = Mesh::gel(12.0, 3.0, 0.15, 4.0, 1.0).unwrap();
        let rs: Vec<f64> = gel_mesh.surface_radii().into_iter().filter(|&r| r < 0.97 * 3.0).collect();
        let hemi = Mesh::hemisphere(3.0, &rs, 12).unwrap();
        let gel = Body::new(gel_mesh, Material { e_mpa: 1.0, nu: 0.48 }).unwrap();
        let ind = Body::new(hemi, Material { e_mpa: 3.0, nu: 0.4 }).unwrap();
        let n = rs.len();
        let c = FrictionalContact::new(rs, gel.surface_compliance_rz(n), &ind.surface_compliance_rz(usize::MAX), 3.0);
        let need = approach_needed(0.8, 3.0, &c.r);
        let s_ref: Vec<f64> = (0..n).map(|i| 1e-3 * (i as f64 * 0.37).sin()).collect();
        let (st, sl, fr) = (Node::Stick, Node::Slip(1.0), Node::Free);
        let patterns: Vec<Vec<Node>> = vec![
            [vec![st; 12], vec![fr; n - 12]].concat(),
            [vec![st; 9], vec![sl, Node::Slip(-1.0), st], vec![fr; n - 12]].concat(),
            [vec![Node::Slip(0.0)], vec![st; 8], vec![fr, st, sl], vec![fr; n - 12]].concat(),
            [vec![st; 3], vec![sl; 9], vec![fr; n - 12]].concat(),
        ];
        let mut stuck =
            StuckCore { factor: PrefixCholesky::empty(), responses: HashMap::new(), rhs_forward: Vec::new() };
        for (k, status) in patterns.iter().enumerate() {
            for mu in [0.3, 1.0] {
                let (u_block, x_block) = c.solve_system(&need, mu, status, &s_ref, Some(&mut stuck)).unwrap();
                let (u_whole, x_whole) = c.solve_system(&need, mu, status, &s_ref, None).unwrap();
                assert_eq!(u_block, u_whole, "pattern {k}");
                let scale = x_whole.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                for (a, b) in x_block.iter().zip(&x_whole) {
                    assert!((a - b).abs() < 1e-9 * scale, "pattern {k} mu {mu}: {a} vs {b}");
                }
            }
        }
        // The factor grew with the largest core and no further.
        assert_eq!(stuck.factor.len(), 2 * 12 - 1);
    }

    /// The disc search on the factor answers as the general active set does, on
    /// an elastic hemisphere pressing a bonded gel from first touch to a contact
    /// near the indenter's radius, in order and out of order (the search starts
    /// from the last answer).
    #[test]
    fn the_disc_search_is_the_active_set_answer() {
        let gel_mesh = Mesh::gel(12.0, 3.0, 0.15, 4.0, 1.0).unwrap();
        let rs: Vec<f64> = gel_mesh.surface_radii().into_iter().filter(|&r| r < 0.97 * 3.0).collect();
        let hemi = Mesh::hemisphere(3.0, &rs, 12).unwrap();
        for nu in [0.3, 0.49] {
            let gel = Body::new(gel_mesh.clone(), Material { e_mpa: 1.0, nu }).unwrap();
            let ind = Body::new(hemi.clone(), Material { e_mpa: 3.0, nu: 0.4 }).unwrap();
            let c = TwoBodyContact::new(&gel, Some(&ind), 3.0).unwrap();
            let mut deltas: Vec<f64> = (1..=24).map(|k| 0.1 * k as f64).collect();
            deltas.extend([0.05, 2.0, 0.7, 1.3]);
            for &d in &deltas {
                let need = approach_needed(d, 3.0, &c.r);
                let disc = c.solve_disc(d, &need).expect("a disc answers a frictionless sphere");
                let general = c.solve_active_set(d, need).unwrap();
                assert_eq!(disc.contact_radius_mm, general.contact_radius_mm, "nu {nu} delta {d}");
                let rel = |a: f64, b: f64| (a - b).abs() / b.abs().max(1e-12);
                assert!(rel(disc.force_n, general.force_n) < 1e-9, "nu {nu} delta {d}");
                assert!(rel(disc.gamma1_mm, general.gamma1_mm) < 1e-9, "nu {nu} delta {d}");
                assert!(disc.nodal_force.iter().all(|&p| p >= 0.0));
            }
        }
    }
}
