//! Torsion about the axis: the circumferential displacement u_θ(r, z) alone
//! (strains γ_rθ = ∂u/∂r - u/r, γ_zθ = ∂u/∂z, energy G(γ_rθ² + γ_zθ²)/2), on the
//! same meshes. Each body condenses to its surface compliance; the contact sticks
//! (no slip), so on the nodes in contact (G_gel + G_ind) T = θ r, and the sensor's
//! theta1 is the area-weighted least-squares twist of the gel's surface over the
//! contact.

use crate::FemError;
use crate::banded::{Banded, Factor};
use crate::mesh::Mesh;
use crate::quad::{self, QuadPoint};

/// Element stiffness (4x4) of one quad for unit shear modulus.
fn element_stiffness(p: [[f64; 2]; 4]) -> [[f64; 4]; 4] {
    let mut ke = [[0.0; 4]; 4];
    for (xi, eta) in quad::gauss_2x2() {
        let Some(QuadPoint { n, grad, r, det }) = quad::at(&p, xi, eta) else {
            continue;
        };
        // Rows γ_rθ, γ_zθ.
        let b: [[f64; 4]; 2] = [std::array::from_fn(|a| grad[a][0] - n[a] / r), std::array::from_fn(|a| grad[a][1])];
        for x in 0..4 {
            for y in 0..4 {
                ke[x][y] += r * det * (b[0][x] * b[0][y] + b[1][x] * b[1][y]);
            }
        }
    }
    ke
}

/// One body in torsion: its factored stiffness for unit shear modulus.
pub struct TorsionBody {
    factor: Factor,
}

impl TorsionBody {
    pub fn new(mesh: &Mesh) -> Result<Self, FemError> {
        let spread = mesh.quads.iter().map(|q| q.iter().max().unwrap_or(&0) - q.iter().min().unwrap_or(&0)).max();
        let mut k = Banded::zeros(mesh.xy.len(), spread.unwrap_or(0));
        for q in &mesh.quads {
            let ke = element_stiffness([mesh.xy[q[0]], mesh.xy[q[1]], mesh.xy[q[2]], mesh.xy[q[3]]]);
            for (x, &nx) in q.iter().enumerate() {
                for (y, &ny) in q.iter().enumerate() {
                    if nx >= ny {
                        k.add(nx, ny, ke[x][y]);
                    }
                }
            }
        }
        let mut rhs = vec![0.0; k.size()];
        for &n in mesh.clamped.iter().chain(&mesh.rollers).chain(&mesh.axis) {
            k.constrain(&mut rhs, n, 0.0);
        }
        // The centre node of a polar mesh is on the axis too.
        for (n, p) in mesh.xy.iter().enumerate() {
            if p[0] == 0.0 {
                k.constrain(&mut rhs, n, 0.0);
            }
        }
        Ok(Self { factor: k.factor()? })
    }

    /// Surface compliance for unit shear modulus: (i, j) the twist displacement at
    /// surface node i under a unit tangential force per radian at node j (column-major).
    pub fn surface_compliance(&self, surface: &[usize]) -> Vec<Vec<f64>> {
        let loads: Vec<Option<(usize, f64)>> = surface.iter().map(|&j| Some((j, 1.0))).collect();
        self.factor.solve_point_loads(&loads, surface)
    }
}

/// theta1 / theta_total with the contact stuck on surface nodes `0..=last`, for
/// compliances already divided by each body's shear modulus; `r` the node radii.
pub fn stick_ratio(g_gel: &[Vec<f64>], g_ind: &[Vec<f64>], r: &[f64], last: usize) -> Option<f64> {
    let m = last + 1;
    // Node 0 sits on the axis (u = 0 there): the unknowns are nodes 1..=last.
    let idx: Vec<usize> = (1..m).collect();
    if idx.is_empty() {
        return None;
    }
    let a: Vec<Vec<f64>> = idx.iter().map(|&i| idx.iter().map(|&j| g_gel[j][i] + g_ind[j][i]).collect()).collect();
    let b: Vec<f64> = idx.iter().map(|&i| r[i]).collect();
    let t = crate::dense::solve(a, b)?;
    // Gel surface twist u_i = Σ G_gel(i, j) T_j; theta1 = Σ w r u / Σ w r² over the contact.
    let mut num = 0.0;
    let mut den = 0.0;
    for (k, &i) in idx.iter().enumerate() {
        let _ = k;
        let u: f64 = idx.iter().enumerate().map(|(l, &j)| g_gel[j][i] * t[l]).sum();
        let lo = if i == 0 { r[0] } else { 0.5 * (r[i - 1] + r[i]) };
        let hi = if i == last { r[i] } else { 0.5 * (r[i] + r[i + 1]) };
        let w = 0.5 * (hi * hi - lo * lo);
        num += w * r[i] * u;
        den += w * r[i] * r[i];
    }
    Some(num / den)
}
