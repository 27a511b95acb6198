//! The bilinear quadrilateral every element of the references is built on:
//! shape functions, their gradients in (r, z) and the axisymmetric volume
//! factor at one point of the parent square.

/// One point of a quad: shape functions, their (d/dr, d/dz) gradients, the
/// point's radius and the Jacobian determinant (area per parent area).
pub(crate) struct QuadPoint {
    pub n: [f64; 4],
    pub grad: [[f64; 2]; 4],
    pub r: f64,
    pub det: f64,
}

/// Corner signs of the parent square, counter-clockwise.
const XI_A: [f64; 4] = [-1.0, 1.0, 1.0, -1.0];
const ETA_A: [f64; 4] = [-1.0, -1.0, 1.0, 1.0];

/// The 2x2 Gauss points of the parent square (weight 1 each).
pub(crate) fn gauss_2x2() -> [(f64, f64); 4] {
    let g = 1.0 / 3f64.sqrt();
    [(-g, -g), (g, -g), (g, g), (-g, g)]
}

/// The quad with corners `p` at parent point (`xi`, `eta`); `None` where it is
/// degenerate or on the axis (r = 0 carries no volume).
pub(crate) fn at(p: &[[f64; 2]; 4], xi: f64, eta: f64) -> Option<QuadPoint> {
    let n: [f64; 4] = std::array::from_fn(|a| 0.25 * (1.0 + xi * XI_A[a]) * (1.0 + eta * ETA_A[a]));
    let dxi: [f64; 4] = std::array::from_fn(|a| 0.25 * XI_A[a] * (1.0 + eta * ETA_A[a]));
    let deta: [f64; 4] = std::array::from_fn(|a| 0.25 * ETA_A[a] * (1.0 + xi * XI_A[a]));
    let (mut j11, mut j12, mut j21, mut j22) = (0.0, 0.0, 0.0, 0.0);
    for a in 0..4 {
        j11 += dxi[a] * p[a][0];
        j12 += dxi[a] * p[a][1];
        j21 += deta[a] * p[a][0];
        j22 += deta[a] * p[a][1];
    }
    let det = j11 * j22 - j12 * j21;
    let r: f64 = (0..4).map(|a| n[a] * p[a][0]).sum();
    if det <= 0.0 || r <= 0.0 {
        return None;
    }
    let grad = std::array::from_fn(|a| [(j22 * dxi[a] - j12 * deta[a]) / det, (-j21 * dxi[a] + j11 * deta[a]) / det]);
    Some(QuadPoint { n, grad, r, det })
}
