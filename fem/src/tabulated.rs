//! The frictionless linear layer law of one rig (a gel layer on its base
//! under one indenter), tabulated in its dimensionless groups (docs/fem.md,
//! "The tabulated law"): the fraction of the approach the gel takes
//! (gamma1 / delta), the force and the contact radius in Hertz's scaling, and
//! theta1 per unit of mount twist, over
//!
//! - kappa = ln(E1 / E2), the modulus ratio,
//! - nu1, the gel's Poisson's ratio,
//! - u = sqrt(delta / R2), the approach (the contact radius grows as sqrt(R2 delta)),
//! - w = rho / (rho + RHO0_RAD), rho = twist / mu, the twist against the friction.
//!
//! The twist needs only rho: without friction in the press, every node's
//! Coulomb limit is mu times its pressure, and the stick/slip problem is
//! linear in the twist and the limits together, so theta1(twist, mu) =
//! mu theta1(twist / mu, 1).
//!
//! Each axis is a Chebyshev grid and the law between its nodes the tensor
//! product of barycentric interpolants: smooth in every group (the FE model
//! steps in its last digits as nodes touch down, the table does not). A
//! fit's model at one (E1, nu1) contracts the material axes once
//! ([`TabulatedLaw::at`]) and then costs a few dozen multiplications a
//! sample. Outside the tabulated ranges the table answers `None` and the
//! caller solves the FE model itself.

use std::f64::consts::PI;

use crate::FemError;
use crate::forward::{FINE_MM, Forward, TwistDisc};

/// Nodes of each axis: ln(E1/E2), nu1, sqrt(delta/R2), the twist variable.
const KAPPA_NODES: usize = 18;
const NU_NODES: usize = 12;
const U_NODES: usize = 16;
const W_NODES: usize = 12;

/// The element size at the contact of the finer mesh that takes the
/// tabulated gamma1 to zero element size, mm.
pub const MESH_FINE_MM: f64 = 0.04;
/// The tabulated modulus ratios E1 / E2.
const E1_OVER_E2: [f64; 2] = [0.01, 10.0];
/// Twist per unit friction (rad) at which the twist variable is one half.
pub const RHO0_RAD: f64 = 0.3;
/// The largest tabulated twist variable (twist / mu = 2.7 rad, 155°).
const W_MAX: f64 = 0.9;
/// Nodes in contact at the shallowest tabulated approach: a smaller contact
/// is a few nodes of the mesh, whose answers step too coarsely to tabulate.
const NODES_AT_SHALLOWEST: f64 = 6.0;
/// Surface nodes left outside the contact at the deepest tabulated approach.
const NODES_LEFT_AT_DEEPEST: usize = 3;

/// One axis: Chebyshev points of the first kind on [lo, hi] and their
/// barycentric weights.
#[derive(Debug, Clone, PartialEq)]
struct Axis {
    lo: f64,
    hi: f64,
    nodes: Vec<f64>,
    bary: Vec<f64>,
}

impl Axis {
    fn chebyshev(lo: f64, hi: f64, n: usize) -> Self {
        let (nodes, bary) = (0..n)
            .map(|j| {
                let t = PI * (2 * j + 1) as f64 / (2 * n) as f64;
                (0.5 * (lo + hi) - 0.5 * (hi - lo) * t.cos(), if j % 2 == 0 { t.sin() } else { -t.sin() })
            })
            .unzip();
        Self { lo, hi, nodes, bary }
    }

    /// The interpolation weights of the nodes at `x` (they sum to one);
    /// `None` outside the axis.
    fn weights(&self, x: f64) -> Option<Vec<f64>> {
        let slack = 1e-12 * (self.hi - self.lo);
        if !(x >= self.lo - slack && x <= self.hi + slack) {
            return None;
        }
        if let Some(k) = self.nodes.iter().position(|&t| (x - t).abs() <= 1e-14 * (self.hi - self.lo)) {
            let mut w = vec![0.0; self.nodes.len()];
            w[k] = 1.0;
            return Some(w);
        }
        let mut w: Vec<f64> = self.nodes.iter().zip(&self.bary).map(|(&t, &b)| b / (x - t)).collect();
        let sum: f64 = w.iter().sum();
        w.iter_mut().for_each(|v| *v /= sum);
        Some(w)
    }
}

/// The law of one rig, tabulated (see the module's documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct TabulatedLaw {
    indenter_e_mpa: f64,
    indenter_r_mm: f64,
    kappa: Axis,
    nu: Axis,
    u: Axis,
    w: Axis,
    /// Every material node's curves, in [kappa][nu] order.
    curves: Curves,
    /// Whether gamma1 is taken to zero element size (false: the layer
    /// model's own mesh, when the finer one could not be solved).
    mesh_limit: bool,
}

/// The tabulated quantities of one material, or of several one after the
/// other: gamma1 / delta, the force over E2 sqrt(R2) delta^1.5 and the
/// contact radius over sqrt(R2 delta) at each approach node, and theta1 per
/// radian of mount twist at [u][w].
#[derive(Debug, Clone, PartialEq, Default)]
struct Curves {
    gamma: Vec<f64>,
    force: Vec<f64>,
    radius: Vec<f64>,
    twist: Vec<f64>,
    /// What taking gamma1 / delta to zero element size added to the layer
    /// model's mesh (included in `gamma`).
    gamma_mesh: Vec<f64>,
    /// The twist taken over the nodes' edge ([`TwistDisc::NodeEdge`]); a
    /// contracted law carries one twist only, in `twist`.
    twist_edge: Vec<f64>,
}

impl TabulatedLaw {
    /// Tabulates `forward`'s law, the material nodes spread over the cores
    /// there are.
    pub fn build(forward: &Forward) -> Result<Self, FemError> {
        let (e2, r2) = (forward.indenter_e_mpa(), forward.indenter_radius_mm());
        let kappa = Axis::chebyshev(E1_OVER_E2[0].ln(), E1_OVER_E2[1].ln(), KAPPA_NODES);
        let nu = Axis::chebyshev(0.0, 0.5, NU_NODES);
        let u_lo = NODES_AT_SHALLOWEST * FINE_MM / r2;
        let u_hi = (deepest_approach_mm(forward, e2, &kappa, &nu)? / r2).sqrt();
        if u_hi.is_nan() || u_hi <= 2.0 * u_lo {
            return Err(FemError::Invalid(format!(
                "the layer model reaches no useful depth under a {r2} mm indenter (deepest tabulated approach {:.4} mm)",
                u_hi * u_hi * r2
            )));
        }
        let u = Axis::chebyshev(u_lo, u_hi, U_NODES);
        let w = Axis::chebyshev(0.0, W_MAX, W_NODES);
        let rho: Vec<f64> = w.nodes.iter().map(|&x| RHO0_RAD * x / (1.0 - x)).collect();
        let materials: Vec<(f64, f64)> =
            kappa.nodes.iter().flat_map(|&k| nu.nodes.iter().map(move |&n| (e2 * k.exp(), n))).collect();
        let node = |&(e1, nu1): &(f64, f64)| -> Result<Curves, FemError> {
            let model = forward.model(e1, nu1);
            let mut v = Curves::default();
            for &x in &u.nodes {
                let delta = r2 * x * x;
                let st = model.normal(delta)?;
                v.gamma.push(st.gamma1_mm / delta);
                v.force.push(st.force_n / (e2 * r2.sqrt() * delta.powf(1.5)));
                v.radius.push(model.contact_radius_mm(&st) / (r2 * delta).sqrt());
                for (disc, to) in [(TwistDisc::Contact, &mut v.twist), (TwistDisc::NodeEdge, &mut v.twist_edge)] {
                    let setup = model.twist_setup_over(&st, 1.0, disc).ok_or_else(|| {
                        FemError::Invalid(format!("no contact off the axis at a {delta:.4} mm approach"))
                    })?;
                    for (t, &r) in model.theta1_rad_sweep(&setup, &rho).into_iter().zip(&rho) {
                        let t = t.ok_or_else(|| FemError::Invalid(format!("no twist at a {delta:.4} mm approach")))?;
                        to.push(t / r);
                    }
                }
            }
            Ok(v)
        };
        let solved = par_map(&materials, node);
        // gamma1 taken to zero element size from this mesh and a finer one
        // (docs/physics.md, "Mesh convergence"): the same rig on
        // MESH_FINE_MM elements pressed to the same approaches.
        // If the finer mesh cannot be built or does not solve a node, the
        // table keeps this mesh's gamma1 throughout and says so
        // ([`TabulatedLaw::mesh_limit`]): a table without the limit is a
        // worse law, not no law.
        let finer = match forward.element_mm() == FINE_MM {
            true => forward
                .cached_on_mesh(MESH_FINE_MM)
                .and_then(|fine| {
                    let node = |&(e1, nu1): &(f64, f64)| -> Result<Vec<f64>, FemError> {
                        let model = fine.model(e1, nu1);
                        u.nodes.iter().map(|&x| Ok(model.normal(r2 * x * x)?.gamma1_mm / (r2 * x * x))).collect()
                    };
                    par_map(&materials, node).into_iter().map(|g| g.map(Some)).collect::<Result<Vec<_>, _>>()
                })
                .ok(),
            false => None,
        };
        let mesh_limit = finer.is_some();
        let finer = finer.unwrap_or_else(|| vec![None; materials.len()]);
        let mut t =
            Self { indenter_e_mpa: e2, indenter_r_mm: r2, kappa, nu, u, w, curves: Curves::default(), mesh_limit };
        for (v, finer) in solved.into_iter().zip(finer) {
            let mut v = v?;
            v.gamma_mesh = vec![0.0; v.gamma.len()];
            if let Some(f) = finer {
                for ((g, m), f) in v.gamma.iter_mut().zip(&mut v.gamma_mesh).zip(f) {
                    let limit = crate::hyper::mesh_extrapolated(f, *g, MESH_FINE_MM, FINE_MM);
                    *m = limit - *g;
                    *g = limit;
                }
            }
            t.curves.gamma_mesh.extend(v.gamma_mesh);
            let c = &mut t.curves;
            c.gamma.extend(v.gamma);
            c.force.extend(v.force);
            c.radius.extend(v.radius);
            c.twist.extend(v.twist);
            c.twist_edge.extend(v.twist_edge);
        }
        Ok(t)
    }

    /// Whether the tabulated gamma1 is taken to zero element size
    /// (docs/physics.md, "Mesh convergence"); false when the finer mesh
    /// could not be built or solved for this rig, and the table holds the
    /// layer model's own mesh (gamma1 then reads about 1-2 µm short at a
    /// dev-set depth).
    pub fn mesh_limit(&self) -> bool {
        self.mesh_limit
    }

    /// The approaches the table covers, mm.
    pub fn approach_range_mm(&self) -> [f64; 2] {
        [self.u.lo, self.u.hi].map(|x| self.indenter_r_mm * x * x)
    }

    /// The law at gel modulus `e1_mpa` and Poisson's ratio `nu1`, its
    /// material axes contracted, theta1 taken over the contact; `None`
    /// outside the tabulated materials.
    pub fn at(&self, e1_mpa: f64, nu1: f64) -> Option<LawAt> {
        self.at_over(e1_mpa, nu1, TwistDisc::Contact)
    }

    /// [`TabulatedLaw::at`] with theta1 taken over `disc`.
    pub fn at_over(&self, e1_mpa: f64, nu1: f64, disc: TwistDisc) -> Option<LawAt> {
        let twist = match disc {
            TwistDisc::Contact => &self.curves.twist,
            TwistDisc::NodeEdge => &self.curves.twist_edge,
        };
        let wk = self.kappa.weights((e1_mpa / self.indenter_e_mpa).ln())?;
        let wn = self.nu.weights(nu1)?;
        let (nu, nw) = (self.u.nodes.len(), self.w.nodes.len());
        let mut at = LawAt {
            indenter_e_mpa: self.indenter_e_mpa,
            indenter_r_mm: self.indenter_r_mm,
            u: self.u.clone(),
            w: self.w.clone(),
            curves: Curves {
                gamma: vec![0.0; nu],
                gamma_mesh: vec![0.0; nu],
                force: vec![0.0; nu],
                radius: vec![0.0; nu],
                twist: vec![0.0; nu * nw],
                twist_edge: Vec::new(),
            },
        };
        let per_material = nu * nw;
        let (to, from) = (&mut at.curves, &self.curves);
        for (i, &a) in wk.iter().enumerate() {
            for (j, &b) in wn.iter().enumerate() {
                let c = a * b;
                let m = i * wn.len() + j;
                let add = |to: &mut [f64], from: &[f64]| to.iter_mut().zip(from).for_each(|(t, f)| *t += c * f);
                add(&mut to.gamma, &from.gamma[m * nu..(m + 1) * nu]);
                add(&mut to.gamma_mesh, &from.gamma_mesh[m * nu..(m + 1) * nu]);
                add(&mut to.force, &from.force[m * nu..(m + 1) * nu]);
                add(&mut to.radius, &from.radius[m * nu..(m + 1) * nu]);
                add(&mut to.twist, &twist[m * per_material..(m + 1) * per_material]);
            }
        }
        Some(at)
    }
}

/// `f` of every item, in their order, on the cores there are (each thread
/// takes the next item left: the items' costs differ).
fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> Result<R, FemError> + Sync) -> Vec<Result<R, FemError>> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, items.len().max(1));
    let mut out: Vec<Option<Result<R, FemError>>> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                scope.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(item) = items.get(i) else { break done };
                        done.push((i, f(item)));
                    }
                })
            })
            .collect();
        let mut out: Vec<Option<Result<R, FemError>>> = (0..items.len()).map(|_| None).collect();
        for w in workers {
            match w.join() {
                Ok(done) => done.into_iter().for_each(|(i, r)| out[i] = Some(r)),
                Err(_) => return vec![Some(Err(FemError::Invalid("a table thread panicked".into())))],
            }
        }
        out
    });
    out.iter_mut()
        .map(|r| r.take().unwrap_or_else(|| Err(FemError::Invalid("a table thread stopped early".into()))))
        .collect()
}

/// The deepest approach at which the contact of every corner of the
/// material grid leaves [`NODES_LEFT_AT_DEEPEST`] surface nodes free, mm:
/// the table ends there.
fn deepest_approach_mm(forward: &Forward, e2: f64, kappa: &Axis, nu: &Axis) -> Result<f64, FemError> {
    let n = forward.surface_nodes();
    let r2 = forward.indenter_radius_mm();
    let mut deepest = f64::INFINITY;
    for k in [kappa.lo, kappa.hi] {
        for v in [nu.lo, nu.hi] {
            let model = forward.model(e2 * k.exp(), v);
            let fits = |delta: f64| -> Result<bool, FemError> {
                let st = model.normal(delta)?;
                Ok(st.nodal_force.iter().rposition(|&p| p > 0.0).is_none_or(|last| last + NODES_LEFT_AT_DEEPEST < n))
            };
            let (mut lo, mut hi) = (0.0, r2);
            if fits(hi)? {
                lo = hi;
            } else {
                for _ in 0..40 {
                    let mid = 0.5 * (lo + hi);
                    if fits(mid)? {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
            }
            deepest = deepest.min(lo);
        }
    }
    Ok(deepest)
}

/// The tabulated law at one material ([`TabulatedLaw::at`]).
#[derive(Debug, Clone)]
pub struct LawAt {
    indenter_e_mpa: f64,
    indenter_r_mm: f64,
    u: Axis,
    w: Axis,
    curves: Curves,
}

impl LawAt {
    /// The approach axis's weights at `delta_mm`: a contact shallower than
    /// the table's takes its shallowest fractions (gamma1 / delta, the
    /// force and radius in Hertz's scaling, theta1 per twist are flat
    /// there, and such a contact is a few mesh nodes wide); `None` past its
    /// deepest or at no approach.
    fn u_weights(&self, delta_mm: f64) -> Option<Vec<f64>> {
        if delta_mm.is_nan() || delta_mm <= 0.0 {
            return None;
        }
        self.u.weights((delta_mm / self.indenter_r_mm).sqrt().max(self.u.lo))
    }

    fn along(&self, values: &[f64], delta_mm: f64) -> Option<f64> {
        let w = self.u_weights(delta_mm)?;
        Some(w.iter().zip(values).map(|(a, b)| a * b).sum())
    }

    /// The gel's deflection on the axis at approach `delta_mm` (> 0), mm;
    /// `None` past the tabulated approaches.
    pub fn gamma1_mm(&self, delta_mm: f64) -> Option<f64> {
        Some(delta_mm * self.along(&self.curves.gamma, delta_mm)?)
    }

    /// The approaches the table covers, mm.
    pub fn approach_range_mm(&self) -> [f64; 2] {
        [self.u.lo, self.u.hi].map(|x| self.indenter_r_mm * x * x)
    }

    /// What taking the layer model to zero element size adds to its gamma1
    /// at approach `delta_mm` (> 0), mm (included in [`LawAt::gamma1_mm`];
    /// added to a press solved on the FE model's own mesh, as where a
    /// recording goes deeper than the table): past the deepest tabulated
    /// approach, the same fraction of the approach as there.
    pub fn mesh_gamma1_mm(&self, delta_mm: f64) -> Option<f64> {
        let d = delta_mm.min(self.approach_range_mm()[1]);
        Some(delta_mm * self.along(&self.curves.gamma_mesh, d)?)
    }

    /// The contact force at approach `delta_mm`, N.
    pub fn force_n(&self, delta_mm: f64) -> Option<f64> {
        Some(
            self.indenter_e_mpa
                * self.indenter_r_mm.sqrt()
                * delta_mm.powf(1.5)
                * self.along(&self.curves.force, delta_mm)?,
        )
    }

    /// The contact's radius at approach `delta_mm`, mm.
    pub fn contact_radius_mm(&self, delta_mm: f64) -> Option<f64> {
        Some((self.indenter_r_mm * delta_mm).sqrt() * self.along(&self.curves.radius, delta_mm)?)
    }

    /// theta1 for a mount twist `twist_rad` at approach `delta_mm` with the
    /// contact's Coulomb friction `mu` (infinite: it sticks), rad; `None`
    /// outside the tabulated approaches or twists.
    pub fn theta1_rad(&self, delta_mm: f64, twist_rad: f64, mu: f64) -> Option<f64> {
        let wu = self.u_weights(delta_mm)?;
        let rho = if mu.is_infinite() { 0.0 } else { twist_rad.abs() / mu };
        let ww = self.w.weights(rho / (rho + RHO0_RAD))?;
        let nw = ww.len();
        let per_twist: f64 = wu
            .iter()
            .enumerate()
            .map(|(i, a)| a * ww.iter().zip(&self.curves.twist[i * nw..(i + 1) * nw]).map(|(b, v)| b * v).sum::<f64>())
            .sum();
        Some(twist_rad * per_twist)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator of points in the table's range.
    struct Points(u64);
    impl Points {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// Between its nodes, across the materials a fit meets (E1/E2 0.05-5,
    /// nu1 0-0.5), the approaches and twists of a sweep and frictions
    /// 0.1-1.1, the table gives what the FE model it was made from gives:
    /// gamma1 within 0.1 µm (a twentieth of the dev set's noise) both on
    /// the model's mesh and taken to zero element size from it and the
    /// finer one, the force within 0.2 %, the contact radius within 2 µm
    /// and theta1 within 0.015° over either disc (the FE model's own steps
    /// as nodes touch down and slip are about that; the table is smooth).
    /// Measured: 0.037 µm, 0.10 %, 0.38 µm, 0.006° over these points
    /// (0.011° at a 0.09 mm press, nine nodes wide, among others).
    #[test]
    fn the_table_reads_the_fe_model_between_its_nodes() {
        let fw = Forward::cached(5.0, 2.0, 0.4, 5.0).unwrap();
        let fine = fw.cached_on_mesh(MESH_FINE_MM).unwrap();
        let table = fw.tabulated().unwrap();
        assert!(table.mesh_limit(), "the dev rig's finer mesh solves: its table is at the mesh limit");
        let [lo, hi] = table.approach_range_mm();
        let mut pts = Points(12345);
        let mut worst = [0.0f64; 4];
        for _ in 0..120 {
            let e1 = 2.0 * (0.05f64.ln() + pts.next() * (100f64).ln()).exp();
            let nu1 = 0.5 * pts.next();
            let delta = lo + (hi - lo) * pts.next();
            let mu = 0.1 + pts.next();
            let twist = (0.5 + 15.0 * pts.next()).to_radians();
            let model = fw.model(e1, nu1);
            let st = model.normal(delta).unwrap();
            let at = table.at(e1, nu1).unwrap();
            let edge_at = table.at_over(e1, nu1, TwistDisc::NodeEdge).unwrap();
            let exact_twist = model.theta1_rad(&st, twist, mu).unwrap();
            let edge = model.twist_setup_over(&st, mu, TwistDisc::NodeEdge).unwrap();
            let edge_twist = model.theta1_rad_at(&edge, twist).unwrap();
            let limit = crate::hyper::mesh_extrapolated(
                fine.model(e1, nu1).normal(delta).unwrap().gamma1_mm,
                st.gamma1_mm,
                MESH_FINE_MM,
                FINE_MM,
            );
            let own_mesh = at.gamma1_mm(delta).unwrap() - at.mesh_gamma1_mm(delta).unwrap();
            let errors = [
                (own_mesh - st.gamma1_mm).abs().max((at.gamma1_mm(delta).unwrap() - limit).abs()) * 1e3,
                (at.force_n(delta).unwrap() / st.force_n - 1.0).abs(),
                (at.contact_radius_mm(delta).unwrap() - model.contact_radius_mm(&st)).abs() * 1e3,
                (at.theta1_rad(delta, twist, mu).unwrap() - exact_twist)
                    .abs()
                    .max((edge_at.theta1_rad(delta, twist, mu).unwrap() - edge_twist).abs())
                    .to_degrees(),
            ];
            worst.iter_mut().zip(errors).for_each(|(w, e)| *w = w.max(e));
        }
        println!(
            "worst: gamma1 {:.3} µm, force {:.2e}, radius {:.2} µm, theta1 {:.4}°",
            worst[0], worst[1], worst[2], worst[3]
        );
        assert!(worst[0] < 0.1 && worst[1] < 2e-3 && worst[2] < 2.0 && worst[3] < 0.015, "{worst:?}");
    }

    /// The twist needs only twist / friction: on a frictionless press every
    /// node's Coulomb limit is mu times its pressure, and the stick/slip
    /// problem is homogeneous in the twist and the limits together, so
    /// theta1(twist, mu) = mu theta1(twist / mu, 1), to rounding, out into
    /// slip.
    #[test]
    fn the_twist_scales_with_the_friction() {
        let fw = Forward::cached(5.0, 2.0, 0.4, 5.0).unwrap();
        let model = fw.model(1.0, 0.48);
        let st = model.normal(1.8).unwrap();
        for (twist_deg, mu) in [(1.0, 0.4), (10.0, 0.4), (10.0, 0.1), (3.0, 2.0)] {
            let twist = f64::to_radians(twist_deg);
            let at_mu = model.theta1_rad(&st, twist, mu).unwrap();
            let scaled = mu * model.theta1_rad(&st, twist / mu, 1.0).unwrap();
            assert!((at_mu - scaled).abs() <= 1e-10 * at_mu.abs(), "{twist_deg}° at mu {mu}: {at_mu} against {scaled}");
        }
    }

    /// Outside what it tabulated the table says so rather than extrapolate:
    /// deeper than its deepest approach, a twist past its range against the
    /// friction, a modulus ratio off its axis; no approach reads nothing.
    #[test]
    fn outside_its_range_the_table_answers_nothing() {
        let fw = Forward::cached(5.0, 2.0, 0.4, 5.0).unwrap();
        let table = fw.tabulated().unwrap();
        let [lo, hi] = table.approach_range_mm();
        assert!(lo < 0.05 && hi > 3.0, "approaches {lo}..{hi} mm");
        let at = table.at(1.0, 0.48).unwrap();
        assert!(at.gamma1_mm(1.01 * hi).is_none() && at.gamma1_mm(0.0).is_none());
        assert!(at.gamma1_mm(0.5 * lo).is_some(), "a shallower contact takes the shallowest fractions");
        let far = RHO0_RAD * W_MAX / (1.0 - W_MAX);
        assert!(at.theta1_rad(1.0, 1.01 * far * 0.1, 0.1).is_none());
        assert!(at.theta1_rad(1.0, 0.99 * far * 0.1, 0.1).is_some());
        assert!(at.theta1_rad(1.0, 0.2, f64::INFINITY).is_some(), "a stuck twist is tabulated");
        assert!(table.at(2.0 * 20.0, 0.4).is_none() && table.at(2.0 * 0.005, 0.4).is_none());
    }
}
