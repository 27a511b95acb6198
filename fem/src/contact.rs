//! Frictionless contact of the indenter with the gel, condensed onto the shared
//! contact-surface nodes: each body is its surface compliance matrix (linear
//! elasticity), and the contact is the linear complementarity problem
//!   (G_gel + G_ind) P = δ - f(r) on the nodes in contact, P >= 0,
//!   no node outside passes through the other body,
//! solved by an active set. f is the exact sphere's profile; gaps are vertical
//! (small strain, small sliding).

use std::f64::consts::PI;

use crate::FemError;
use crate::elastic::Body;

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
}

/// The gel and the indenter (rigid when `None`), condensed onto their common surface nodes.
pub struct TwoBodyContact {
    radius_mm: f64,
    r: Vec<f64>,
    g_gel: Vec<Vec<f64>>,
    g_sum: Vec<Vec<f64>>,
}

/// Solve the dense system a x = b (Gaussian elimination with partial pivoting).
pub(crate) fn dense_solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for c in 0..n {
        let p = (c..n).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[p][c].abs() < 1e-300 {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        for i in c + 1..n {
            let f = a[i][c] / a[c][c];
            if f != 0.0 {
                for k in c..n {
                    a[i][k] -= f * a[c][k];
                }
                b[i] -= f * b[c];
            }
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|k| a[i][k] * x[k]).sum();
        x[i] = (b[i] - s) / a[i][i];
    }
    Some(x)
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
        Ok(Self { radius_mm: indenter_radius_mm, r: r_gel[..n].to_vec(), g_gel, g_sum })
    }

    /// From compliance matrices already on common surface nodes at radii `r`
    /// (column-major: `g[j][i]` is node i's response to a load on node j).
    pub fn from_compliances(r: Vec<f64>, g_gel: Vec<Vec<f64>>, g_ind: &[Vec<f64>], indenter_radius_mm: f64) -> Self {
        let n = r.len();
        let g_sum = (0..n).map(|j| (0..n).map(|i| g_gel[j][i] + g_ind[j][i]).collect()).collect();
        Self { radius_mm: indenter_radius_mm, r, g_gel, g_sum }
    }

    pub fn radii(&self) -> &[f64] {
        &self.r
    }

    fn profile(&self, r: f64) -> f64 {
        let big = self.radius_mm;
        big - (big * big - r * r).max(0.0).sqrt()
    }

    /// The contact at platform approach `delta_mm`.
    pub fn solve(&self, delta_mm: f64) -> Result<ContactState, FemError> {
        let n = self.r.len();
        let need: Vec<f64> = self.r.iter().map(|&r| delta_mm - self.profile(r)).collect();
        let mut active: Vec<bool> = need.iter().map(|&d| d > 0.0).collect();
        let mut p = vec![0.0; n];
        let mut passes_releasing = 0;
        for _ in 0..4 * n + 10 {
            let idx: Vec<usize> = (0..n).filter(|&i| active[i]).collect();
            let a: Vec<Vec<f64>> = idx.iter().map(|&i| idx.iter().map(|&j| self.g_sum[j][i]).collect()).collect();
            let b: Vec<f64> = idx.iter().map(|&i| need[i]).collect();
            let x =
                if idx.is_empty() { Vec::new() } else { dense_solve(a, b).ok_or(FemError::NotPositiveDefinite(0))? };
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
                let gamma1: f64 = (0..n).map(|j| self.g_gel[j][0] * p[j]).sum();
                let last = (0..n).rev().find(|&i| active[i]).unwrap_or(0);
                return Ok(ContactState {
                    delta_mm,
                    force_n: 2.0 * PI * p.iter().sum::<f64>(),
                    gamma1_mm: gamma1,
                    gamma2_mm: delta_mm - gamma1,
                    contact_radius_mm: [self.r[last], self.r.get(last + 1).copied().unwrap_or(self.r[last])],
                    nodal_force: p,
                });
            }
            for i in entering {
                active[i] = true;
            }
        }
        Err(FemError::ContactNotSettled(4 * n + 10))
    }
}
