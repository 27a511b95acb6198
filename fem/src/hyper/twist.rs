//! Small twist of the deformed contact (docs/physics.md, "Large strain"): each
//! body's twist stiffness about its deformed state, condensed onto the contact
//! points, with Coulomb stick and slip at the normal forces of the solved state.

use super::{LargeState, LargeStrainContact};
use crate::FemError;
use crate::dense;

impl LargeStrainContact {
    /// theta1 (rad) for a platform twist `twist_rad` (monotone from 0) at the
    /// current state (`st` its solved state): small twist of the deformed bodies,
    /// stick where the tangential force is under `mu` times the normal one and slip
    /// at that limit beyond; theta1 the area-weighted least-squares twist of the
    /// gel's surface over the contact (current radii).
    pub fn theta1_rad(&self, st: &LargeState, twists_rad: &[f64], mu: f64) -> Result<Vec<f64>, FemError> {
        let (fg, ig) = self.gel.twist_factor()?;
        let (fi, ii) = self.indenter.twist_factor()?;
        let nodes: Vec<usize> = (1..self.slaves.len()).filter(|&k| st.meets[k].is_some()).collect();
        if nodes.is_empty() {
            return Err(FemError::Invalid("no contact to twist".into()));
        }
        let r: Vec<f64> = nodes.iter().map(|&k| st.radius_mm[k]).collect();
        // Compliances in twist angle per unit moment per radian.
        let loads: Vec<Vec<f64>> = nodes
            .iter()
            .map(|&l| {
                let mut e = vec![0.0; fg_len(&ig)];
                if let Some(d) = ig[self.slaves[l]] {
                    e[d] = 1.0;
                }
                e
            })
            .collect();
        let cg: Vec<Vec<f64>> = fg
            .solve_many(&loads)
            .iter()
            .map(|x| nodes.iter().map(|&k| ig[self.slaves[k]].map_or(0.0, |d| x[d])).collect())
            .collect();
        let weights = |k: usize| -> [(usize, f64); 2] {
            let (m, xi) = st.meets[k].unwrap_or((0, 0.0));
            [(self.chain[m], 1.0 - xi), (self.chain[m + 1], xi)]
        };
        let loads: Vec<Vec<f64>> = nodes
            .iter()
            .map(|&l| {
                let mut e = vec![0.0; fg_len(&ii)];
                for (n, w) in weights(l) {
                    if let Some(d) = ii[n] {
                        e[d] += w;
                    }
                }
                e
            })
            .collect();
        let ci: Vec<Vec<f64>> = fi
            .solve_many(&loads)
            .iter()
            .map(|x| {
                nodes.iter().map(|&k| weights(k).iter().map(|&(n, w)| ii[n].map_or(0.0, |d| w * x[d])).sum()).collect()
            })
            .collect();
        let n = nodes.len();
        // Unknown: moments per radian M = r T on the contact nodes; stick: Σ (Cg + Ci) M = Θ.
        let cap: Vec<f64> = nodes.iter().zip(&r).map(|(&k, &rk)| mu * st.nodal_force[k] * rk).collect();
        let mut out = Vec::with_capacity(twists_rad.len());
        let mut slip = vec![false; n];
        for &theta in twists_rad {
            let mut m = vec![0.0; n];
            for _ in 0..=n {
                let stick: Vec<usize> = (0..n).filter(|&k| !slip[k]).collect();
                let a: Vec<Vec<f64>> =
                    stick.iter().map(|&k| stick.iter().map(|&l| cg[l][k] + ci[l][k]).collect()).collect();
                let b: Vec<f64> = stick
                    .iter()
                    .map(|&k| theta - (0..n).filter(|&l| slip[l]).map(|l| (cg[l][k] + ci[l][k]) * cap[l]).sum::<f64>())
                    .collect();
                let x = if stick.is_empty() {
                    Vec::new()
                } else {
                    dense::solve(a, b).ok_or(FemError::NotPositiveDefinite(0))?
                };
                for k in 0..n {
                    m[k] = if slip[k] { cap[k] } else { 0.0 };
                }
                for (j, &k) in stick.iter().enumerate() {
                    m[k] = x[j];
                }
                let over: Vec<usize> = (0..n).filter(|&k| !slip[k] && m[k] > cap[k]).collect();
                if over.is_empty() {
                    break;
                }
                over.into_iter().for_each(|k| slip[k] = true);
            }
            let (mut num, mut den) = (0.0, 0.0);
            for k in 0..n {
                let phi: f64 = (0..n).map(|l| cg[l][k] * m[l]).sum();
                let lo = if k == 0 { 0.5 * r[0] } else { 0.5 * (r[k - 1] + r[k]) };
                let hi = if k + 1 == n { r[k] } else { 0.5 * (r[k] + r[k + 1]) };
                let w = 0.5 * (hi * hi - lo * lo);
                num += w * r[k] * r[k] * phi;
                den += w * r[k] * r[k];
            }
            out.push(num / den);
        }
        Ok(out)
    }
}

fn fg_len(idx: &[Option<usize>]) -> usize {
    idx.iter().flatten().max().map_or(0, |m| m + 1)
}
