//! One neo-Hookean body on a quadrilateral mesh (docs/physics.md, "Large
//! strain"): the element's stress and tangent, the free-dof numbering with a
//! narrow band, and the small-twist stiffness about a deformed state.

use crate::FemError;
use crate::banded::{Banded, Factor};
use crate::elastic::{Integration, Material};
use crate::mesh::Mesh;
use crate::quad::{self, QuadPoint};

/// The deformation gradient's five non-zero components in the physical
/// cylindrical bases, in the order (rR, rZ, zR, zZ, θΘ); indices (current,
/// reference) with r = 0, z = 1, θ = 2.
const COMPONENTS: [(usize, usize); 5] = [(0, 0), (0, 1), (1, 0), (1, 1), (2, 2)];

/// Stress (first Piola–Kirchhoff, 5 components) and tangent (5x5) of one part of
/// the split energy at one point, for deformation gradient `f`.
fn stress_tangent(f: &[f64; 5], mu: f64, bulk: f64, volumetric: bool, safe: bool) -> Option<([f64; 5], [[f64; 5]; 5])> {
    let (a, b, c, d, t) = (f[0], f[1], f[2], f[3], f[4]);
    let j2 = a * d - b * c;
    let jac = j2 * t;
    if !(jac > 0.0 && j2 > 0.0 && t > 0.0) {
        return None;
    }
    let ln_j = jac.ln();
    // H = F^-T as a 3x3 (current, reference) matrix.
    let mut h = [[0.0; 3]; 3];
    h[0][0] = d / j2;
    h[0][1] = -c / j2;
    h[1][0] = -b / j2;
    h[1][1] = a / j2;
    h[2][2] = 1.0 / t;
    let hv: [f64; 5] = std::array::from_fn(|k| h[COMPONENTS[k].0][COMPONENTS[k].1]);
    // d(F^-T)_iJ / dF_kL = -H_kJ H_iL.
    let t2 = |x: usize, y: usize| {
        let (i, jj) = COMPONENTS[x];
        let (k, l) = COMPONENTS[y];
        h[k][jj] * h[i][l]
    };
    let mut p = [0.0; 5];
    let mut tan = [[0.0; 5]; 5];
    if volumetric {
        // P = K ln J H.
        for x in 0..5 {
            p[x] = bulk * ln_j * hv[x];
            for y in 0..5 {
                let stress_part = if safe { 0.0 } else { bulk * ln_j * t2(x, y) };
                tan[x][y] = bulk * hv[x] * hv[y] - stress_part;
            }
        }
    } else {
        // P = mu (F - H) - (2 mu / 3) ln J H.
        let c3 = 2.0 * mu / 3.0;
        for x in 0..5 {
            p[x] = mu * (f[x] - hv[x]) - c3 * ln_j * hv[x];
            for y in 0..5 {
                let unit = if x == y { mu } else { 0.0 };
                let coef = if safe { mu } else { mu + c3 * ln_j };
                tan[x][y] = unit + coef * t2(x, y) - c3 * hv[x] * hv[y];
            }
        }
    }
    Some((p, tan))
}

/// Internal force (8) and, when `tangent`, tangent stiffness (8x8; zeros
/// otherwise) per radian of one quad with reference corners `p` and
/// displacements `u`; `None` if the element inverts.
fn element(
    p: [[f64; 2]; 4],
    u: [[f64; 2]; 4],
    m: &Material,
    integration: Integration,
    safe: bool,
    tangent: bool,
) -> Option<([f64; 8], [[f64; 8]; 8])> {
    let mu = m.e_mpa / (2.0 * (1.0 + m.nu));
    let bulk = m.e_mpa / (3.0 * (1.0 - 2.0 * m.nu));
    let mut fe = [0.0; 8];
    let mut ke = [[0.0; 8]; 8];
    let mut add = |xi: f64, eta: f64, weight: f64, volumetric: bool| -> Option<()> {
        let Some(QuadPoint { n, grad, r, det }) = quad::at(&p, xi, eta) else {
            return Some(());
        };
        // G maps the element's dofs (u_r, u_z per node) to the five F components.
        let mut g = [[0.0; 8]; 5];
        for a in 0..4 {
            let [dr, dz] = grad[a];
            g[0][2 * a] = dr;
            g[1][2 * a] = dz;
            g[2][2 * a + 1] = dr;
            g[3][2 * a + 1] = dz;
            g[4][2 * a] = n[a] / r;
        }
        let mut f = [1.0, 0.0, 0.0, 1.0, 1.0];
        for x in 0..5 {
            for c in 0..8 {
                f[x] += g[x][c] * u[c / 2][c % 2];
            }
        }
        let (s, tan) = stress_tangent(&f, mu, bulk, volumetric, safe)?;
        let w = weight * r * det;
        if !tangent {
            for c in 0..8 {
                fe[c] += w * (0..5).map(|x| g[x][c] * s[x]).sum::<f64>();
            }
            return Some(());
        }
        let mut tg = [[0.0; 8]; 5];
        for x in 0..5 {
            for c in 0..8 {
                tg[x][c] = (0..5).map(|y| tan[x][y] * g[y][c]).sum();
            }
        }
        for c in 0..8 {
            fe[c] += w * (0..5).map(|x| g[x][c] * s[x]).sum::<f64>();
            for e in 0..8 {
                ke[c][e] += w * (0..5).map(|x| g[x][c] * tg[x][e]).sum::<f64>();
            }
        }
        Some(())
    };
    for (xi, eta) in quad::gauss_2x2() {
        add(xi, eta, 1.0, false)?;
        if integration == Integration::Full {
            add(xi, eta, 1.0, true)?;
        }
    }
    if integration == Integration::Selective {
        add(0.0, 0.0, 4.0, true)?;
    }
    Some((fe, ke))
}

/// Reverse Cuthill–McKee order of the nodes `keep` (a small bandwidth for the
/// banded factor); returns each kept node's rank.
fn rcm_rank(mesh: &Mesh, keep: &[bool]) -> Vec<Option<usize>> {
    let nn = mesh.xy.len();
    let mut adj: Vec<Vec<usize>> = vec![Vec::new(); nn];
    for q in &mesh.quads {
        for &a in q {
            for &b in q {
                if a != b && keep[a] && keep[b] && !adj[a].contains(&b) {
                    adj[a].push(b);
                }
            }
        }
    }
    let mut order = Vec::with_capacity(nn);
    let mut seen = vec![false; nn];
    loop {
        let start = (0..nn).filter(|&i| keep[i] && !seen[i]).min_by_key(|&i| adj[i].len());
        let Some(s) = start else { break };
        seen[s] = true;
        let mut queue = std::collections::VecDeque::from([s]);
        while let Some(v) = queue.pop_front() {
            order.push(v);
            let mut next: Vec<usize> = adj[v].iter().copied().filter(|&w| !seen[w]).collect();
            next.sort_by_key(|&w| adj[w].len());
            for w in next {
                seen[w] = true;
                queue.push_back(w);
            }
        }
    }
    order.reverse();
    let mut rank = vec![None; nn];
    for (k, &v) in order.iter().enumerate() {
        rank[v] = Some(k);
    }
    rank
}

/// One neo-Hookean body: reference mesh, displacements, and the numbering of its
/// free degrees of freedom (clamped nodes follow the support; axis nodes have
/// u_r = 0).
pub struct HyperBody {
    pub mesh: Mesh,
    pub material: Material,
    /// Displacements (u_r, u_z) per node, mm.
    pub u: Vec<[f64; 2]>,
    pub(super) dof: Vec<[Option<usize>; 2]>,
    pub(super) free: usize,
    bw: usize,
    /// Where the elements integrate their volumetric part.
    pub integration: Integration,
}

impl HyperBody {
    pub fn new(mesh: Mesh, material: Material) -> Result<Self, FemError> {
        if !(material.e_mpa > 0.0 && material.nu > 0.0 && material.nu < 0.5) {
            return Err(FemError::Invalid(format!("material E {} MPa, nu {}", material.e_mpa, material.nu)));
        }
        let nn = mesh.xy.len();
        let mut roller = vec![false; nn];
        mesh.rollers.iter().for_each(|&n| roller[n] = true);
        let mut clamped = vec![false; nn];
        mesh.clamped.iter().for_each(|&n| clamped[n] = true);
        let mut on_axis = vec![false; nn];
        mesh.axis.iter().for_each(|&n| on_axis[n] = true);
        for (n, p) in mesh.xy.iter().enumerate() {
            if p[0] == 0.0 {
                on_axis[n] = true;
            }
        }
        let keep: Vec<bool> = clamped.iter().map(|c| !c).collect();
        // The narrowest band of a few orders: reverse Cuthill–McKee, by columns
        // (r then z), by rows, and by spokes about the top of the body's axis
        // (a hemisphere's polar grid).
        let top = mesh.xy.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max);
        let keys: [&dyn Fn(usize) -> (f64, f64); 3] =
            [&|n| (mesh.xy[n][0], mesh.xy[n][1]), &|n| (mesh.xy[n][1], mesh.xy[n][0]), &|n| {
                let [r, z] = mesh.xy[n];
                ((r.atan2(top - z) * 1e9).round(), r.hypot(top - z))
            }];
        let mut orders: Vec<Vec<usize>> = keys
            .iter()
            .map(|key| {
                let mut o: Vec<usize> = (0..nn).filter(|&n| keep[n]).collect();
                o.sort_by(|&a, &b| {
                    let (ka, kb) = (key(a), key(b));
                    ka.0.total_cmp(&kb.0).then(ka.1.total_cmp(&kb.1))
                });
                o
            })
            .collect();
        let rank = rcm_rank(&mesh, &keep);
        let mut rcm: Vec<(usize, usize)> = rank.iter().enumerate().filter_map(|(n, r)| r.map(|r| (r, n))).collect();
        rcm.sort();
        orders.push(rcm.into_iter().map(|(_, n)| n).collect());
        let numbering = |order: &[usize]| {
            let mut dof = vec![[None, None]; nn];
            let mut free = 0;
            for &n in order {
                if !on_axis[n] {
                    dof[n][0] = Some(free);
                    free += 1;
                }
                if !roller[n] {
                    dof[n][1] = Some(free);
                    free += 1;
                }
            }
            let mut bw = 0;
            for q in &mesh.quads {
                let ds: Vec<usize> = q.iter().flat_map(|&n| dof[n].iter().flatten().copied()).collect();
                if let (Some(lo), Some(hi)) = (ds.iter().min(), ds.iter().max()) {
                    bw = bw.max(hi - lo);
                }
            }
            (bw, free, dof)
        };
        let (bw, free, dof) = orders
            .iter()
            .map(|o| numbering(o))
            .min_by_key(|x| x.0)
            .ok_or_else(|| FemError::Invalid("an empty mesh".into()))?;
        Ok(Self { u: vec![[0.0; 2]; nn], mesh, material, dof, free, bw, integration: Integration::Selective })
    }

    /// Current position of node `n`.
    pub fn x(&self, n: usize) -> [f64; 2] {
        [self.mesh.xy[n][0] + self.u[n][0], self.mesh.xy[n][1] + self.u[n][1]]
    }

    /// Tangent (banded, free dofs; when asked) and internal force on the free dofs.
    pub(super) fn assemble(&self, tangent: bool, safe: bool) -> Result<(Option<Banded>, Vec<f64>), FemError> {
        let mut k = tangent.then(|| Banded::zeros(self.free, self.bw));
        let mut f = vec![0.0; self.free];
        for q in &self.mesh.quads {
            let p = q.map(|n| self.mesh.xy[n]);
            let u = q.map(|n| self.u[n]);
            let (fe, ke) = element(p, u, &self.material, self.integration, safe, tangent)
                .ok_or(FemError::Inverted(self.material.e_mpa))?;
            for (x, &nx) in q.iter().enumerate() {
                for cx in 0..2 {
                    let Some(dx) = self.dof[nx][cx] else { continue };
                    f[dx] += fe[2 * x + cx];
                    let Some(k) = k.as_mut() else { continue };
                    for (y, &ny) in q.iter().enumerate() {
                        for cy in 0..2 {
                            if let Some(dy) = self.dof[ny][cy]
                                && dx >= dy
                            {
                                k.add(dx, dy, ke[2 * x + cx][2 * y + cy]);
                            }
                        }
                    }
                }
            }
        }
        Ok((k, f))
    }

    /// The factored tangent; where large strain makes the full tangent indefinite
    /// (its initial-stress terms), the positive part without them (the residual
    /// stays exact, so only the iteration's rate changes).
    pub(super) fn tangent(&self) -> Result<Factor, FemError> {
        let full = self.assemble(true, false)?.0.ok_or(FemError::NotPositiveDefinite(0))?;
        match full.factor() {
            Ok(f) => Ok(f),
            Err(_) => self.assemble(true, true)?.0.ok_or(FemError::NotPositiveDefinite(0))?.factor(),
        }
    }

    /// The free dofs' displacements as one vector.
    pub(super) fn free_values(&self) -> Vec<f64> {
        let mut v = vec![0.0; self.free];
        for (n, d) in self.dof.iter().enumerate() {
            for c in 0..2 {
                if let Some(i) = d[c] {
                    v[i] = self.u[n][c];
                }
            }
        }
        v
    }

    pub(super) fn set_free_values(&mut self, v: &[f64]) {
        for (n, d) in self.dof.iter().enumerate() {
            for c in 0..2 {
                if let Some(i) = d[c] {
                    self.u[n][c] = v[i];
                }
            }
        }
    }

    /// Tangent stiffness of the small twist about the current state, per unit
    /// shear modulus times mu: energy ½ ∫ mu r² |∇φ|² dV over the reference, φ the
    /// twist angle, r the current radius; clamped nodes held (φ = 0).
    pub(super) fn twist_factor(&self) -> Result<(Factor, Vec<Option<usize>>), FemError> {
        let mu = self.material.e_mpa / (2.0 * (1.0 + self.material.nu));
        let nn = self.mesh.xy.len();
        let mut idx = vec![None; nn];
        let mut clamped = vec![false; nn];
        self.mesh.clamped.iter().chain(&self.mesh.rollers).for_each(|&n| clamped[n] = true);
        let mut count = 0;
        // The same order as the in-plane dofs (small band).
        let mut order: Vec<(usize, usize)> =
            (0..nn).filter(|&n| !clamped[n]).map(|n| (self.dof[n][1].unwrap_or(0), n)).collect();
        order.sort();
        for (_, n) in order {
            idx[n] = Some(count);
            count += 1;
        }
        let mut bw = 0;
        for q in &self.mesh.quads {
            let ds: Vec<usize> = q.iter().filter_map(|&n| idx[n]).collect();
            if let (Some(lo), Some(hi)) = (ds.iter().min(), ds.iter().max()) {
                bw = bw.max(hi - lo);
            }
        }
        let mut k = Banded::zeros(count, bw);
        for q in &self.mesh.quads {
            let p = q.map(|n| self.mesh.xy[n]);
            let ur = q.map(|n| self.u[n][0]);
            for (xi, eta) in quad::gauss_2x2() {
                let Some(QuadPoint { n, grad, r: r0, det }) = quad::at(&p, xi, eta) else {
                    continue;
                };
                let r: f64 = r0 + (0..4).map(|a| n[a] * ur[a]).sum::<f64>();
                let w = mu * r * r * r0 * det;
                for x in 0..4 {
                    let Some(dx) = idx[q[x]] else { continue };
                    for y in 0..4 {
                        let Some(dy) = idx[q[y]] else { continue };
                        if dx >= dy {
                            k.add(dx, dy, w * (grad[x][0] * grad[y][0] + grad[x][1] * grad[y][1]));
                        }
                    }
                }
            }
        }
        Ok((k.factor()?, idx))
    }
}
