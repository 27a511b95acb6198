//! Axisymmetric linear elasticity on a quadrilateral mesh: bilinear isoparametric
//! elements with selective reduced integration (deviatoric part 2x2 Gauss,
//! volumetric part one point, so a nearly incompressible gel does not lock).
//! Stiffness per radian of circumference: forces are 2π times the nodal values.

use crate::FemError;
use crate::banded::{Banded, Factor};
use crate::mesh::Mesh;
use crate::quad::{self, QuadPoint};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    pub e_mpa: f64,
    pub nu: f64,
}

impl Material {
    fn shear(&self) -> f64 {
        self.e_mpa / (2.0 * (1.0 + self.nu))
    }
    fn bulk(&self) -> f64 {
        self.e_mpa / (3.0 * (1.0 - 2.0 * self.nu))
    }
}

const D_DEV: [[f64; 4]; 4] = [
    [4.0 / 3.0, -2.0 / 3.0, -2.0 / 3.0, 0.0],
    [-2.0 / 3.0, 4.0 / 3.0, -2.0 / 3.0, 0.0],
    [-2.0 / 3.0, -2.0 / 3.0, 4.0 / 3.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// Where an element integrates its volumetric part.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Integration {
    /// At the element's centre, the rest at 2x2 Gauss points: no locking as
    /// nu -> 0.5. The references' own element.
    #[default]
    Selective,
    /// At the 2x2 Gauss points like the rest. It locks slightly (about 0.1 %
    /// in gamma1 at nu1 = 0.48 on the 0.06 mm mesh), but at large strain it
    /// stays stable where the selective element's hourglass modes give way
    /// (docs/physics.md, "Large strain"): the large-strain table's extension
    /// in depth comes from it.
    Full,
}

/// Element stiffness (8x8, dofs u_r, u_z per node) of one quad.
fn element_stiffness(p: [[f64; 2]; 4], m: &Material, integration: Integration) -> [[f64; 8]; 8] {
    let (mu, kb) = (m.shear(), m.bulk());
    let mut ke = [[0.0; 8]; 8];
    let mut add = |xi: f64, eta: f64, weight: f64, volumetric: bool| {
        let Some(QuadPoint { n, grad, r, det }) = quad::at(&p, xi, eta) else {
            return;
        };
        let mut b = [[0.0; 8]; 4];
        for a in 0..4 {
            let [dndr, dndz] = grad[a];
            b[0][2 * a] = dndr;
            b[1][2 * a + 1] = dndz;
            b[2][2 * a] = n[a] / r;
            b[3][2 * a] = dndz;
            b[3][2 * a + 1] = dndr;
        }
        let w = weight * r * det;
        let mut db = [[0.0; 8]; 4];
        for (row, dbr) in db.iter_mut().enumerate() {
            for (c, v) in dbr.iter_mut().enumerate() {
                *v = if volumetric {
                    if row < 3 { kb * (b[0][c] + b[1][c] + b[2][c]) } else { 0.0 }
                } else {
                    mu * (0..4).map(|q| D_DEV[row][q] * b[q][c]).sum::<f64>()
                };
            }
        }
        for x in 0..8 {
            for y in 0..8 {
                ke[x][y] += w * (0..4).map(|q| b[q][x] * db[q][y]).sum::<f64>();
            }
        }
    };
    for (xi, eta) in quad::gauss_2x2() {
        add(xi, eta, 1.0, false);
        if integration == Integration::Full {
            add(xi, eta, 1.0, true);
        }
    }
    if integration == Integration::Selective {
        add(0.0, 0.0, 4.0, true);
    }
    ke
}

/// One elastic body: its mesh, material and factored stiffness with its supports.
pub struct Body {
    pub mesh: Mesh,
    pub material: Material,
    factor: Factor,
}

impl Body {
    /// Assemble and factor the stiffness with the mesh's clamped, roller and axis nodes held.
    pub fn new(mesh: Mesh, material: Material) -> Result<Self, FemError> {
        Self::with_integration(mesh, material, Integration::Selective)
    }

    /// [`Self::new`] with the volumetric part integrated as `integration` says.
    pub fn with_integration(mesh: Mesh, material: Material, integration: Integration) -> Result<Self, FemError> {
        if !(material.e_mpa > 0.0 && material.nu > 0.0 && material.nu < 0.5) {
            return Err(FemError::Invalid(format!("material E {} MPa, nu {}", material.e_mpa, material.nu)));
        }
        let mut k = Banded::zeros(2 * mesh.xy.len(), mesh.bandwidth());
        for q in &mesh.quads {
            let p = [mesh.xy[q[0]], mesh.xy[q[1]], mesh.xy[q[2]], mesh.xy[q[3]]];
            let ke = element_stiffness(p, &material, integration);
            for (x, &nx) in q.iter().enumerate() {
                for (y, &ny) in q.iter().enumerate() {
                    for (cx, cy) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                        let (dx, dy) = (2 * nx + cx, 2 * ny + cy);
                        if dx >= dy {
                            k.add(dx, dy, ke[2 * x + cx][2 * y + cy]);
                        }
                    }
                }
            }
        }
        let mut rhs = vec![0.0; k.size()];
        for &n in &mesh.clamped {
            k.constrain(&mut rhs, 2 * n, 0.0);
            k.constrain(&mut rhs, 2 * n + 1, 0.0);
        }
        for &n in &mesh.rollers {
            k.constrain(&mut rhs, 2 * n + 1, 0.0);
        }
        for &n in &mesh.axis {
            k.constrain(&mut rhs, 2 * n, 0.0);
        }
        let factor = k.factor()?;
        Ok(Self { mesh, material, factor })
    }

    /// Compliance of the contact surface: entry (i, j) is the vertical displacement
    /// of surface node i, toward the body, under a unit vertical force per radian
    /// on node j pressing into the body (mm per N/rad).
    pub fn surface_compliance(&self) -> Vec<Vec<f64>> {
        let s = &self.mesh.surface;
        // Which way "into the body" is: down for the gel (surface on top), up for the indenter.
        let into = |node: usize| {
            let z = self.mesh.xy[node][1];
            let mean = self.mesh.xy.iter().map(|p| p[1]).sum::<f64>() / self.mesh.xy.len() as f64;
            if mean < z { -1.0 } else { 1.0 }
        };
        let sign = into(s[0]);
        let loads: Vec<Option<(usize, f64)>> = s.iter().map(|&j| Some((2 * j + 1, sign))).collect();
        let keep: Vec<usize> = s.iter().map(|&i| 2 * i + 1).collect();
        self.factor.solve_point_loads(&loads, &keep).into_iter().map(|u| u.iter().map(|v| sign * v).collect()).collect()
    }

    /// The full surface compliance in global (r, z) components on the first
    /// `nodes` surface nodes (all of them if fewer): for a unit force per radian
    /// along r or z at surface node j, the r and z displacements at each of those
    /// nodes (column-major blocks, `rr[j][i]` is u_r at i under F_r at j). The
    /// axis node carries no radial force (its u_r is held), so its radial column
    /// is zero.
    pub fn surface_compliance_rz(&self, nodes: usize) -> SurfaceCompliance {
        let s = &self.mesh.surface[..nodes.min(self.mesh.surface.len())];
        let held: std::collections::HashSet<usize> = self.mesh.axis.iter().copied().collect();
        // Unit loads along r then z at each node, solved together; a held
        // radial dof takes no load (zero column). Of each solution only the
        // surface nodes' u_r and u_z are kept, node by node.
        let loads: Vec<Option<(usize, f64)>> = s
            .iter()
            .flat_map(|&j| [(j, 0), (j, 1)])
            .map(|(j, dof)| (!(dof == 0 && held.contains(&j))).then_some((2 * j + dof, 1.0)))
            .collect();
        let keep: Vec<usize> = s.iter().flat_map(|&i| [2 * i, 2 * i + 1]).collect();
        let u = self.factor.solve_point_loads(&loads, &keep);
        let split = |u: &[f64]| -> (Vec<f64>, Vec<f64>) {
            (u.iter().step_by(2).copied().collect(), u.iter().skip(1).step_by(2).copied().collect())
        };
        let mut out = SurfaceCompliance::default();
        for pair in u.chunks(2) {
            let (rr, zr) = split(&pair[0]);
            let (rz, zz) = split(&pair[1]);
            out.rr.push(rr);
            out.zr.push(zr);
            out.rz.push(rz);
            out.zz.push(zz);
        }
        out
    }
}

/// A body's surface compliance in global components (see
/// [`Body::surface_compliance_rz`]): `ab[j][i]` is the a-displacement at node i
/// under a unit b-force per radian at node j.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SurfaceCompliance {
    pub rr: Vec<Vec<f64>>,
    pub rz: Vec<Vec<f64>>,
    pub zr: Vec<Vec<f64>>,
    pub zz: Vec<Vec<f64>>,
}

impl SurfaceCompliance {
    /// `Σ_k w_k m_k / scale` on the leading `n` nodes, block by block (an
    /// interpolation between tables).
    pub fn combine(parts: &[(f64, &Self)], n: usize, scale: f64) -> Self {
        let mix = |pick: &dyn Fn(&Self) -> &Vec<Vec<f64>>| {
            let blocks: Vec<(f64, &Vec<Vec<f64>>)> = parts.iter().map(|(w, m)| (*w, pick(m))).collect();
            combine_block(&blocks, n, scale)
        };
        Self { rr: mix(&|m| &m.rr), rz: mix(&|m| &m.rz), zr: mix(&|m| &m.zr), zz: mix(&|m| &m.zz) }
    }
}

/// `Σ_k w_k m_k / scale` of column-major matrices on their leading `n` nodes.
pub fn combine_block(parts: &[(f64, &Vec<Vec<f64>>)], n: usize, scale: f64) -> Vec<Vec<f64>> {
    (0..n)
        .map(|j| {
            let mut col = vec![0.0; n];
            for (w, m) in parts {
                let f = w / scale;
                col.iter_mut().zip(&m[j][..n]).for_each(|(c, v)| *c += f * v);
            }
            col
        })
        .collect()
}
