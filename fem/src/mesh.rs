//! Quadrilateral meshes of the two bodies' cross-sections (r >= 0, z up): the
//! gel on a graded tensor grid, the indenter's hemisphere on a polar grid whose
//! surface nodes sit at chosen radii (so both contact surfaces share them).

use std::f64::consts::FRAC_PI_2;

use crate::FemError;

#[derive(Debug, Clone, PartialEq)]
pub struct Mesh {
    /// Node coordinates (r, z), mm.
    pub xy: Vec<[f64; 2]>,
    /// Elements, counter-clockwise in (r, z).
    pub quads: Vec<[usize; 4]>,
    /// Nodes with both displacements fixed (bonded to something rigid).
    pub clamped: Vec<usize>,
    /// Nodes resting on something rigid and frictionless: held normal to it
    /// (u_z = 0), free along it (u_r); the twist holds them, as it holds
    /// the clamped ones ([`Base::Sliding`]).
    pub rollers: Vec<usize>,
    /// Nodes on the axis (u_r = 0).
    pub axis: Vec<usize>,
    /// Contact-surface nodes, by increasing radius.
    pub surface: Vec<usize>,
}

/// How the gel's bottom face sits on its window.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Base {
    /// Bonded: both displacements held.
    #[default]
    Bonded,
    /// Resting on the window without friction in the press (u_z held, u_r
    /// free). The twist is held at the base as for a bonded gel, as the
    /// analytical layer model takes it (docs/physics.md, "Layered contact").
    Sliding,
}

/// Points from 0 to `length`: steps of `fine` up to `fine_until`, then growing by
/// `growth` per step (never larger than `coarse`).
pub fn graded(length: f64, fine: f64, fine_until: f64, growth: f64, coarse: f64) -> Vec<f64> {
    let mut x = vec![0.0];
    let mut step = fine;
    let mut last = 0.0;
    while last < length - 1e-12 {
        if last >= fine_until - 1e-12 {
            step = (step * growth).min(coarse);
        }
        last = (last + step).min(length);
        x.push(last);
    }
    let n = x.len();
    if n > 2 && x[n - 1] - x[n - 2] < 0.3 * step {
        x.remove(n - 2);
    }
    x
}

impl Mesh {
    /// Half-bandwidth in degrees of freedom (two per node).
    pub fn bandwidth(&self) -> usize {
        let spread = self.quads.iter().map(|q| q.iter().max().unwrap_or(&0) - q.iter().min().unwrap_or(&0)).max();
        2 * spread.unwrap_or(0) + 1
    }

    /// The gel: radius `radius_mm`, thickness `thickness_mm`, bottom clamped, top
    /// surface the contact; elements of `fine_mm` within `fine_radius_mm` of the
    /// axis and `fine_depth_mm` of the surface, growing beyond.
    pub fn gel(
        radius_mm: f64,
        thickness_mm: f64,
        fine_mm: f64,
        fine_radius_mm: f64,
        fine_depth_mm: f64,
    ) -> Result<Self, FemError> {
        if !(radius_mm > 0.0 && thickness_mm > 0.0 && fine_mm > 0.0 && fine_mm < thickness_mm) {
            return Err(FemError::Invalid(format!(
                "gel radius {radius_mm} mm, thickness {thickness_mm} mm, element size {fine_mm} mm"
            )));
        }
        let r = graded(radius_mm, fine_mm, fine_radius_mm, 1.15, 2.0);
        let depth = graded(thickness_mm, fine_mm, fine_depth_mm, 1.15, 1.0);
        let z: Vec<f64> = depth.iter().rev().map(|d| -d).collect();
        let nz = z.len();
        let node = |i: usize, j: usize| i * nz + j;
        let mut xy = Vec::with_capacity(r.len() * nz);
        for &ri in &r {
            for &zj in &z {
                xy.push([ri, zj]);
            }
        }
        let mut quads = Vec::new();
        for i in 0..r.len() - 1 {
            for j in 0..nz - 1 {
                quads.push([node(i, j), node(i + 1, j), node(i + 1, j + 1), node(i, j + 1)]);
            }
        }
        Ok(Self {
            xy,
            quads,
            rollers: Vec::new(),
            clamped: (0..r.len()).map(|i| node(i, 0)).collect(),
            axis: (0..nz).map(|j| node(0, j)).collect(),
            surface: (0..r.len()).map(|i| node(i, nz - 1)).collect(),
        })
    }

    /// The same mesh with its clamped nodes on `base`: kept clamped on a
    /// bonded one, rollers on a sliding one.
    pub fn on_base(mut self, base: Base) -> Self {
        if base == Base::Sliding {
            self.rollers.append(&mut self.clamped);
        }
        self
    }

    /// Radii of the contact-surface nodes.
    pub fn surface_radii(&self) -> Vec<f64> {
        self.surface.iter().map(|&n| self.xy[n][0]).collect()
    }

    /// The indenter: a hemisphere of radius `radius_mm`, tip at z = 0, its flat top
    /// (z = radius) clamped to the platform. Surface nodes at the radii `surface_r`
    /// (increasing from 0, below the radius), then coarser to the equator; `rings`
    /// radial layers graded toward the surface.
    pub fn hemisphere(radius_mm: f64, surface_r: &[f64], rings: usize) -> Result<Self, FemError> {
        let big = radius_mm;
        if !(big > 0.0 && rings >= 4) || surface_r.first() != Some(&0.0) || surface_r.iter().any(|&r| r >= 0.99 * big) {
            return Err(FemError::Invalid("hemisphere: surface radii must start at 0 and stay below 0.99 R".into()));
        }
        // Polar angle from the downward axis: phi = asin(r / R), then to pi/2.
        let mut phi: Vec<f64> = surface_r.iter().map(|r| (r / big).asin()).collect();
        let last = *phi.last().unwrap_or(&0.0);
        let step = (phi[phi.len() - 1] - phi[phi.len().saturating_sub(2)]).max(0.05);
        let extra = ((FRAC_PI_2 - last) / step).ceil().max(4.0) as usize;
        for k in 1..=extra {
            phi.push(last + (FRAC_PI_2 - last) * k as f64 / extra as f64);
        }
        // Radial layers: fine at the surface (rho = R), coarse toward the centre.
        let mut rho: Vec<f64> = (0..=rings).map(|k| big * (1.0 - (1.0 - k as f64 / rings as f64).powi(2))).collect();
        rho[rings] = big;
        let np = phi.len();
        // Node numbering: ring by ring from the centre; the centre is one node.
        let centre = 0usize;
        let node = |k: usize, p: usize| if k == 0 { centre } else { 1 + (k - 1) * np + p };
        let mut xy = vec![[0.0, big]];
        for &rk in &rho[1..] {
            for &ph in &phi {
                xy.push([rk * ph.sin(), big - rk * ph.cos()]);
            }
        }
        let mut quads = Vec::new();
        for k in 0..rings {
            for p in 0..np - 1 {
                // Counter-clockwise in (r, z): outer ring has lower z near the tip.
                quads.push([node(k, p), node(k + 1, p), node(k + 1, p + 1), node(k, p + 1)]);
            }
        }
        let mut clamped = vec![centre];
        clamped.extend((1..=rings).map(|k| node(k, np - 1)));
        let axis = (1..=rings).map(|k| node(k, 0)).collect();
        let surface = (0..surface_r.len()).map(|p| node(rings, p)).collect();
        Ok(Self { xy, quads, clamped, rollers: Vec::new(), axis, surface })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn graded_grid_is_fine_then_grows() {
        let x = graded(15.0, 0.05, 5.0, 1.15, 2.0);
        assert_eq!(x[0], 0.0);
        assert!((x[x.len() - 1] - 15.0).abs() < 1e-12);
        assert!(x.windows(2).all(|w| w[1] > w[0]));
        assert!((x[1] - 0.05).abs() < 1e-12 && (x[100] - 5.0).abs() < 1e-9);
    }

    #[test]
    fn meshes_have_positive_areas_and_their_surfaces() {
        let g = Mesh::gel(15.0, 5.0, 0.1, 5.0, 1.0).unwrap();
        let r = g.surface_radii();
        let h = Mesh::hemisphere(5.0, &r[..40], 12).unwrap();
        for m in [&g, &h] {
            for q in &m.quads {
                let p: Vec<[f64; 2]> = q.iter().map(|&n| m.xy[n]).collect();
                let area2: f64 = (0..4).map(|i| p[i][0] * p[(i + 1) % 4][1] - p[(i + 1) % 4][0] * p[i][1]).sum();
                assert!(area2 >= 0.0, "{q:?} {p:?}");
            }
        }
        for (k, &n) in h.surface.iter().enumerate() {
            let [rr, zz] = h.xy[n];
            assert!((rr - r[k]).abs() < 1e-12);
            assert!(((rr * rr + (5.0 - zz).powi(2)).sqrt() - 5.0).abs() < 1e-12);
        }
    }
}
