//! The two small robust fits behind a measurement: a quadratic surface around
//! the deepest point of the normal field, and a 2-D Procrustes rotation of the
//! stuck markers about the contact centre. Both reject outlier markers by a
//! robust (median-based) scale and refit.

use nalgebra::{Matrix2, Matrix4, SMatrix, SVector, U4, Vector2, Vector4};

use sim::sensor::shape::SurfaceShape;

use crate::numerics::lm::{self, LmError, LmOptions, NormalEquations, Problem, Strategy};
use crate::numerics::stats::{MAD_TO_SIGMA, median, rms};

/// w = c0 + c1 x + c2 y + c3 x^2 + c4 x y + c5 y^2, in coordinates local to the window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quadratic {
    pub c: [f64; 6],
}

impl Quadratic {
    pub fn value(&self, x: f64, y: f64) -> f64 {
        let c = &self.c;
        c[0] + c[1] * x + c[2] * y + c[3] * x * x + c[4] * x * y + c[5] * y * y
    }

    /// The stationary point and the value there, if the surface has a
    /// maximum (negative definite Hessian).
    pub fn maximum(&self) -> Option<([f64; 2], f64)> {
        let c = &self.c;
        let (hxx, hxy, hyy) = (2.0 * c[3], c[4], 2.0 * c[5]);
        let det = hxx * hyy - hxy * hxy;
        if !(hxx < 0.0 && det > 0.0) {
            return None;
        }
        // H [x y]^T = -[c1 c2]^T.
        let x = (-c[1] * hyy + c[2] * hxy) / det;
        let y = (-c[2] * hxx + c[1] * hxy) / det;
        Some(([x, y], self.value(x, y)))
    }

    /// Half the Hessian's trace, (w_xx + w_yy) / 2 (-gamma1 / a^2 for Hertz).
    pub fn mean_curvature(&self) -> f64 {
        self.c[3] + self.c[5]
    }
}

/// Result of [`fit_quadratic`].
#[derive(Debug, Clone)]
pub struct QuadraticFit {
    pub surface: Quadratic,
    /// Per input point: kept in the final fit.
    pub kept: Vec<bool>,
    /// RMS residual of the kept points, mm.
    pub rms: f64,
}

/// Least-squares quadratic surface through `(x, y, w)` with outlier
/// rejection: the point with the largest externally studentised residual is
/// dropped while that exceeds about `k` sigmas (and its residual `floor`),
/// one at a time. `isotropic` fits w = c0 + c1 x + c2 y + c3 (x^2 + y^2)
/// (the shape of an axisymmetric Hertz contact: two fewer unknowns, so
/// outliers stand out better in a small window); otherwise the general
/// six-term quadratic. `None` if too few points remain or they do not
/// determine the surface.
pub fn fit_quadratic(pts: &[[f64; 3]], isotropic: bool, k: f64, floor: f64) -> Option<QuadraticFit> {
    if isotropic {
        let (c, kept, rms) = fit_linear::<4>(pts, |x, y| [1.0, x, y, x * x + y * y], k, floor)?;
        Some(QuadraticFit { surface: Quadratic { c: [c[0], c[1], c[2], c[3], 0.0, c[3]] }, kept, rms })
    } else {
        let (c, kept, rms) = fit_linear::<6>(pts, |x, y| [1.0, x, y, x * x, x * y, y * y], k, floor)?;
        Some(QuadraticFit { surface: Quadratic { c }, kept, rms })
    }
}

/// Linear least squares in `P` basis functions of (x, y), with one-at-a-time
/// outlier removal. Returns the coefficients, the kept mask and the RMS.
fn fit_linear<const P: usize>(
    pts: &[[f64; 3]],
    basis: impl Fn(f64, f64) -> [f64; P] + Copy,
    k: f64,
    floor: f64,
) -> Option<([f64; P], Vec<bool>, f64)> {
    let n = pts.len();
    let first = remove_outliers(pts, basis, k, floor, vec![true; n]);
    let Some((_, kept1, _)) = &first else { return first };
    if kept1.iter().all(|&b| b) || n > 40 || n < P + 4 {
        return first.map(|f| readmit(pts, basis, k, floor, f));
    }
    // Two outliers in a small window can mask each other (the first removal
    // then takes a good point): also start from the best pair removed, and
    // keep whichever fit explains more points better.
    let second = best_pair_removed(pts, basis).and_then(|mask| remove_outliers(pts, basis, k, floor, mask));
    let score = |f: &([f64; P], Vec<bool>, f64)| {
        let kept = f.1.iter().filter(|&&b| b).count().max(1) as f64;
        f.2 * (n as f64 / kept).sqrt()
    };
    let best = match (first, second) {
        (Some(a), Some(b)) => Some(if score(&b) < score(&a) { b } else { a }),
        (a, b) => a.or(b),
    };
    best.map(|f| readmit(pts, basis, k, floor, f))
}

/// Standard errors of the isotropic paraboloid w = c0 + c1 x + c2 y + c3 r^2
/// fitted to the kept points: of its value at `at` (the peak: there the
/// slope is zero, so the peak value moves with the coefficients as the basis
/// at `at` says) and of its curvature 2 c3. The marker noise is taken from
/// the fit's own residuals, `rms` over the kept points. `None` when the
/// points leave no spare degree of freedom or do not determine the surface.
pub fn paraboloid_errors(pts: &[[f64; 3]], kept: &[bool], at: [f64; 2], rms: f64) -> Option<(f64, f64)> {
    let basis = |x: f64, y: f64| [1.0, x, y, x * x + y * y];
    let m = kept.iter().filter(|&&b| b).count();
    if m <= 4 {
        return None;
    }
    let (ata, _, _) = normal_equations(pts, basis, kept);
    let inv = ata.try_inverse()?;
    let s2 = rms * rms * m as f64 / (m - 4) as f64;
    let g = SVector::<f64, 4>::from(basis(at[0], at[1]));
    let var_value = s2 * (g.transpose() * inv * g)[0];
    let var_curvature = 4.0 * s2 * inv[(3, 3)];
    (var_value >= 0.0 && var_curvature >= 0.0).then(|| (var_value.sqrt(), var_curvature.sqrt()))
}

fn normal_equations<const P: usize>(
    pts: &[[f64; 3]],
    basis: impl Fn(f64, f64) -> [f64; P],
    kept: &[bool],
) -> (SMatrix<f64, P, P>, SVector<f64, P>, f64) {
    let mut ata = SMatrix::<f64, P, P>::zeros();
    let mut atb = SVector::<f64, P>::zeros();
    let mut btb = 0.0;
    for (p, _) in pts.iter().zip(kept).filter(|(_, k)| **k) {
        let a = SVector::<f64, P>::from(basis(p[0], p[1]));
        ata += a * a.transpose();
        atb += a * p[2];
        btb += p[2] * p[2];
    }
    (ata, atb, btb)
}

/// The mask with the pair of points removed whose absence leaves the
/// smallest squared residual sum (by down-dating the normal equations).
fn best_pair_removed<const P: usize>(
    pts: &[[f64; 3]],
    basis: impl Fn(f64, f64) -> [f64; P] + Copy,
) -> Option<Vec<bool>> {
    let n = pts.len();
    let (ata, atb, btb) = normal_equations(pts, basis, &vec![true; n]);
    let rows: Vec<SVector<f64, P>> = pts.iter().map(|p| SVector::<f64, P>::from(basis(p[0], p[1]))).collect();
    let mut best: Option<(f64, usize, usize)> = None;
    for i in 0..n {
        for j in i + 1..n {
            let (ai, aj) = (&rows[i], &rows[j]);
            let a2 = ata - ai * ai.transpose() - aj * aj.transpose();
            let b2 = atb - ai * pts[i][2] - aj * pts[j][2];
            let Some(c) = a2.cholesky().map(|ch| ch.solve(&b2)) else { continue };
            let ssr = btb - pts[i][2] * pts[i][2] - pts[j][2] * pts[j][2] - c.dot(&b2);
            if best.is_none_or(|(s, _, _)| ssr < s) {
                best = Some((ssr, i, j));
            }
        }
    }
    let (_, i, j) = best?;
    let mut mask = vec![true; n];
    mask[i] = false;
    mask[j] = false;
    Some(mask)
}

/// Take back removed points that the final fit explains as well as the kept
/// ones (a good point dropped while an outlier still pulled the fit).
fn readmit<const P: usize>(
    pts: &[[f64; 3]],
    basis: impl Fn(f64, f64) -> [f64; P],
    k: f64,
    floor: f64,
    fit: ([f64; P], Vec<bool>, f64),
) -> ([f64; P], Vec<bool>, f64) {
    let (c, mut kept, rms) = fit;
    let coef = SVector::<f64, P>::from(c);
    let limit = (k * rms).max(floor);
    let mut changed = false;
    for (i, p) in pts.iter().enumerate() {
        if !kept[i] && (p[2] - coef.dot(&SVector::<f64, P>::from(basis(p[0], p[1])))).abs() <= limit {
            kept[i] = true;
            changed = true;
        }
    }
    if !changed {
        return (c, kept, rms);
    }
    let (ata, atb, _) = normal_equations(pts, &basis, &kept);
    let Some(inv) = ata.try_inverse() else { return (c, kept, rms) };
    let coef = inv * atb;
    let m = kept.iter().filter(|&&b| b).count().max(1);
    let ssr: f64 = pts
        .iter()
        .zip(&kept)
        .filter(|(_, k)| **k)
        .map(|(p, _)| (p[2] - coef.dot(&SVector::<f64, P>::from(basis(p[0], p[1])))).powi(2))
        .sum();
    let mut out = [0.0; P];
    out.copy_from_slice(coef.as_slice());
    (out, kept, (ssr / m as f64).sqrt())
}

/// One-at-a-time removal of the most significant outlier, from `kept`.
fn remove_outliers<const P: usize>(
    pts: &[[f64; 3]],
    basis: impl Fn(f64, f64) -> [f64; P],
    k: f64,
    floor: f64,
    mut kept: Vec<bool>,
) -> Option<([f64; P], Vec<bool>, f64)> {
    let n = pts.len();
    let mut removed = kept.iter().filter(|&&b| !b).count();
    loop {
        let m = kept.iter().filter(|&&b| b).count();
        if m < P + 1 {
            return None;
        }
        let mut ata = SMatrix::<f64, P, P>::zeros();
        let mut atb = SVector::<f64, P>::zeros();
        for (p, _) in pts.iter().zip(&kept).filter(|(_, k)| **k) {
            let a = SVector::<f64, P>::from(basis(p[0], p[1]));
            ata += a * a.transpose();
            atb += a * p[2];
        }
        let inv = ata.try_inverse()?;
        let coef = inv * atb;
        // The point whose removal lowers the squared residual sum most
        // (by r^2 / (1 - h)) is tested against the scatter of the others:
        // its externally studentised residual. Judging it by the scatter of
        // all points would let an outlier hide behind its own pull on a fit
        // with only a few spare points.
        let mut ssr = 0.0;
        let mut worst: Option<(usize, f64)> = None;
        for (i, p) in pts.iter().enumerate() {
            if !kept[i] {
                continue;
            }
            let a = SVector::<f64, P>::from(basis(p[0], p[1]));
            let r = p[2] - coef.dot(&a);
            ssr += r * r;
            let h = (a.transpose() * inv * a)[0].clamp(0.0, 1.0);
            // A point the fit must pass through (h = 1) cannot be judged.
            let drop = if h < 1.0 - 1e-9 { r * r / (1.0 - h) } else { 0.0 };
            if worst.is_none_or(|(_, d)| drop > d) {
                worst = Some((i, drop));
            }
        }
        let rms = (ssr / m as f64).sqrt();
        let spare = m.saturating_sub(P + 1);
        let outlier = worst.filter(|&(_, drop)| {
            if spare < 2 {
                return false;
            }
            let dof = spare as f64;
            let s2 = (ssr - drop).max(0.0) / dof;
            // Few spare points give a t distribution with heavy tails.
            let limit = k * (1.0 + 2.0 / dof);
            drop.sqrt() > floor && drop > limit * limit * s2
        });
        match outlier {
            Some((i, _)) if removed < n / 4 => {
                kept[i] = false;
                removed += 1;
            }
            _ => {
                let mut c = [0.0; P];
                c.copy_from_slice(coef.as_slice());
                return Some((c, kept, rms));
            }
        }
    }
}

/// Result of [`fit_rotation`].
#[derive(Debug, Clone)]
pub struct RotationFit {
    /// Rotation about +z, rad.
    pub theta: f64,
    pub kept: Vec<bool>,
    /// RMS tangential residual displacement of the kept markers, mm.
    pub rms: f64,
    /// Sum of squared distances of the kept markers from the centre, mm^2.
    pub sum_r2: f64,
    /// How far the kept markers moved out (> 1) or in (< 1) from the centre
    /// besides turning: |(sum p.q, sum p x q)| / sum |p|^2. A Hertz contact
    /// draws its markers in (nu1 < 0.5), and the angle's noise grows as
    /// 1 / scale: theta = atan2(sum p x q, sum p.q).
    pub scale: f64,
}

impl RotationFit {
    /// The standard error of `theta` (rad) for a tangential marker noise
    /// `noise_mm`: noise / (sqrt(sum r^2) scale).
    pub fn theta_sd(&self, noise_mm: f64) -> f64 {
        noise_mm / (self.sum_r2.sqrt() * self.scale)
    }
}

/// The rotation about `centre` that best maps the reference points `p` onto
/// the displaced points `q` (orthogonal Procrustes via the SVD of the 2 x 2
/// cross-covariance), with outlier markers rejected by the robust scale of
/// the tangential residuals. The centre is held fixed, not fitted: with a free
/// translation the symmetric radial contraction of a Hertz contact would leak
/// into the angle whenever the stuck markers are not symmetric about it.
pub fn fit_rotation(p: &[[f64; 2]], q: &[[f64; 2]], centre: [f64; 2], k: f64, floor: f64) -> Option<RotationFit> {
    let n = p.len();
    let mut kept = vec![true; n];
    const ROUNDS: usize = 6;
    for round in 0..ROUNDS {
        let m = kept.iter().filter(|&&b| b).count();
        if m < 2 {
            return None;
        }
        let mut h = Matrix2::<f64>::zeros();
        let mut sum_r2 = 0.0;
        for i in (0..n).filter(|&i| kept[i]) {
            let (px, py) = (p[i][0] - centre[0], p[i][1] - centre[1]);
            let (qx, qy) = (q[i][0] - centre[0], q[i][1] - centre[1]);
            h += Matrix2::new(px * qx, px * qy, py * qx, py * qy);
            sum_r2 += px * px + py * py;
        }
        if sum_r2 <= 0.0 {
            return None;
        }
        let svd = h.svd(true, true);
        let (u, v_t) = (svd.u?, svd.v_t?);
        let mut rot = v_t.transpose() * u.transpose();
        if rot.determinant() < 0.0 {
            // A reflection fits better than any rotation: flip the weakest axis.
            let mut v = v_t.transpose();
            v.set_column(1, &(-v.column(1)));
            rot = v * u.transpose();
        }
        let theta = rot[(1, 0)].atan2(rot[(0, 0)]);
        let (s, c) = theta.sin_cos();
        // Judge markers by the tangential part of the residual only: the
        // radial part holds the contact's non-rigid radial contraction
        // (Hertz, nu < 0.5), which does not bear on the angle.
        let resid: Vec<f64> = (0..n)
            .map(|i| {
                let (px, py) = (p[i][0] - centre[0], p[i][1] - centre[1]);
                let (qx, qy) = (q[i][0] - centre[0], q[i][1] - centre[1]);
                let (rx, ry) = (c * px - s * py, s * px + c * py);
                let len = rx.hypot(ry);
                if len > 0.0 { (rx * qy - ry * qx).abs() / len } else { 0.0 }
            })
            .collect();
        let mut kept_r: Vec<f64> = (0..n).filter(|&i| kept[i]).map(|i| resid[i]).collect();
        let rms = rms(&kept_r);
        let sigma = MAD_TO_SIGMA * median(&mut kept_r);
        let limit = (k * sigma).max(floor);
        // Re-judge every marker against the current fit (one wrongly dropped
        // in an early, pulled fit comes back).
        let next: Vec<bool> = resid.iter().map(|&e| e <= limit).collect();
        if round + 1 == ROUNDS || next.iter().filter(|&&b| b).count() < 2 || next == kept {
            let scale = (h[(0, 0)] + h[(1, 1)]).hypot(h[(0, 1)] - h[(1, 0)]) / sum_r2;
            return Some(RotationFit { theta, kept, rms, sum_r2, scale });
        }
        kept = next;
    }
    None
}

/// Hertz normal displacement w(r) / w(0) at rho = r / a (Johnson 1985, Eqs. 3.41-3.42).
pub fn hertz_shape(rho: f64) -> f64 {
    if rho <= 1.0 {
        1.0 - 0.5 * rho * rho
    } else {
        ((2.0 - rho * rho) * (1.0 / rho).asin() + (rho * rho - 1.0).sqrt()) / std::f64::consts::PI
    }
}

/// [`hertz_shape`] and [`hertz_slope`] at `rho` together (one arcsine).
fn hertz_shape_and_slope(rho: f64) -> (f64, f64) {
    if rho <= 1.0 {
        return (1.0 - 0.5 * rho * rho, -rho);
    }
    let (s, root) = ((1.0 / rho).asin(), (rho * rho - 1.0).sqrt());
    (((2.0 - rho * rho) * s + root) / std::f64::consts::PI, std::f64::consts::FRAC_2_PI * (root / rho - rho * s))
}

/// d hertz_shape / d rho.
pub fn hertz_slope(rho: f64) -> f64 {
    if rho <= 1.0 {
        -rho
    } else {
        std::f64::consts::FRAC_2_PI * ((rho * rho - 1.0).sqrt() / rho - rho * (1.0 / rho).asin())
    }
}

/// The normal field's shape w / gamma1 at `r` from the centre of a contact
/// of radius `a`: Hertz's ([`hertz_shape`]), plus a declared layer's
/// departure from it (docs/sensing.md, "On a layer").
#[inline]
pub fn field_shape(layer: Option<&SurfaceShape>, r: f64, a: f64) -> f64 {
    hertz_shape(r / a) + layer.map_or(0.0, |l| l.departure(r, a))
}

/// [`field_shape`] and its derivatives in `r` and in `a` (the layer's part
/// by central differences over its table).
#[inline]
fn field_shape_d(layer: Option<&SurfaceShape>, r: f64, a: f64) -> [f64; 3] {
    let rho = r / a;
    let (f, fp) = hertz_shape_and_slope(rho);
    let mut out = [f, fp / a, -fp * rho / a];
    if let Some(l) = layer {
        let h = 1e-3 * a;
        out[0] += l.departure(r, a);
        out[1] += (l.departure(r + h, a) - l.departure(r - h, a)) / (2.0 * h);
        out[2] += (l.departure(r, a + h) - l.departure(r, a - h)) / (2.0 * h);
    }
    out
}

/// What the Hertz field fit knows of the field's curvature inside the
/// contact, gamma1 / a^2 (docs/sensing.md, "Small contacts").
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Curvature {
    /// Nothing: depth and radius are both free.
    Free,
    /// At most `max_per_mm` (the indenter's curvature): a fit whose radius
    /// ends under `below_mm` beyond it is redone on the bound.
    Bounded { max_per_mm: f64, below_mm: f64 },
    /// Measured on this run's resolved contacts, with its standard error: the
    /// radius follows the depth, a = sqrt(gamma1 / c).
    Known { per_mm: f64, sd_per_mm: f64 },
}

/// Result of [`fit_hertz`].
#[derive(Debug, Clone)]
pub struct HertzFit {
    pub gamma1: f64,
    pub centre: [f64; 2],
    pub radius: f64,
    pub kept: Vec<bool>,
    pub rms: f64,
    /// Standard error of gamma1: the fit's own (marker noise through the
    /// Jacobian) and, with a known curvature, that curvature's.
    pub gamma1_sd: f64,
    /// Standard error of the curvature gamma1 / a^2 when the fit left the
    /// radius free (`None` when it was tied).
    pub curvature_sd: Option<f64>,
    /// The marker noise the errors were computed with: the residual rms
    /// corrected for the free parameters, mm; and those degrees of freedom.
    pub noise_sd: f64,
    pub dof: usize,
    /// The part of `gamma1_sd` that the known curvature's error makes, mm:
    /// common to every frame fitted with that curvature, so averaging frames
    /// does not shrink it (0 when the fit did not use one).
    pub gamma1_common_sd: f64,
}

/// Fit the Hertz normal field w = gamma1 f(|p - c| / a) to `(x, y, w)` by
/// Levenberg-Marquardt in (gamma1, cx, cy, a), starting from `start`, then
/// reject outliers by a robust scale and refit. Used when the contact is too
/// small for the quadratic window to stay inside it: outside the contact the
/// field is no paraboloid, but it still is Hertz's.
///
/// Below about a marker pitch the markers mostly see the field outside the
/// contact, which fixes gamma1 * a but hardly gamma1 and a apart; `curvature`
/// says what settles that (see [`Curvature`]).
///
/// `fixed_centre`: the centre is known (`start`'s) and held, not fitted.
/// `layer`: a declared gel layer's field shape ([`field_shape`]).
#[allow(clippy::too_many_arguments)]
pub fn fit_hertz(
    pts: &[[f64; 3]],
    layer: Option<&SurfaceShape>,
    start: (f64, [f64; 2], f64),
    k: f64,
    floor: f64,
    curvature: Curvature,
    fixed_centre: bool,
) -> Option<HertzFit> {
    let n = pts.len();
    let mut kept = vec![true; n];
    let mut params = [start.0, start.1[0], start.1[1], start.2];
    let mut tie = match curvature {
        Curvature::Known { per_mm, .. } if per_mm > 0.0 => Some(per_mm),
        _ => None,
    };
    const ROUNDS: usize = 4;
    for round in 0..ROUNDS {
        params = lm_hertz(pts, layer, &kept, params, tie, fixed_centre)?;
        if let Curvature::Bounded { max_per_mm, below_mm } = curvature
            && max_per_mm > 0.0
            && params[3] < below_mm
            && params[0] > max_per_mm * params[3] * params[3]
        {
            tie = Some(max_per_mm);
            params = lm_hertz(pts, layer, &kept, params, tie, fixed_centre)?;
        }
        let [g, cx, cy, a] = params;
        let resid: Vec<f64> =
            pts.iter().map(|p| p[2] - g * field_shape(layer, (p[0] - cx).hypot(p[1] - cy), a)).collect();
        let mut kr: Vec<f64> = (0..n).filter(|&i| kept[i]).map(|i| resid[i].abs()).collect();
        let rms = rms(&kr);
        let limit = (k * MAD_TO_SIGMA * median(&mut kr)).max(floor);
        let next: Vec<bool> = resid.iter().map(|e| e.abs() <= limit).collect();
        if round + 1 == ROUNDS || next == kept || next.iter().filter(|&&b| b).count() < 5 {
            let cov = hertz_covariance(pts, layer, &kept, params, tie, fixed_centre, rms)?;
            let mut gamma1_sd = cov[(0, 0)].sqrt();
            let mut gamma1_common_sd = 0.0;
            // Untied, the fit measures the curvature g / a^2 itself.
            let curvature_sd = tie.is_none().then(|| {
                let j = [1.0 / (a * a), -2.0 * g / (a * a * a)];
                (j[0] * j[0] * cov[(0, 0)] + 2.0 * j[0] * j[1] * cov[(0, 3)] + j[1] * j[1] * cov[(3, 3)]).sqrt()
            });
            if let (Some(_), Curvature::Known { per_mm, sd_per_mm }) = (tie, curvature) {
                // The curvature's own error, through how far gamma1 moves
                // when the fit is redone with another c.
                gamma1_common_sd = tied_gamma1_per_curvature(pts, layer, &kept, params, per_mm) * sd_per_mm;
                gamma1_sd = gamma1_sd.hypot(gamma1_common_sd);
            }
            let m = kept.iter().filter(|&&b| b).count();
            let free = 4 - usize::from(tie.is_some()) - 2 * usize::from(fixed_centre);
            let dof = m.saturating_sub(free);
            return Some(HertzFit {
                noise_sd: if dof > 0 { rms * (m as f64 / dof as f64).sqrt() } else { f64::NAN },
                dof,
                gamma1: g,
                centre: [cx, cy],
                radius: a,
                kept,
                rms,
                gamma1_sd,
                curvature_sd,
                gamma1_common_sd,
            });
        }
        kept = next;
    }
    None
}

/// The least sum of squares of the field `layer` over the kept markers at a
/// held centre, with depth and radius free from `start` (gamma1, cx, cy, a):
/// how well that field's shape fits them (mm²).
pub fn field_sse(pts: &[[f64; 3]], layer: &SurfaceShape, kept: &[bool], start: [f64; 4]) -> Option<f64> {
    let p = lm_hertz(pts, Some(layer), kept, start, None, true)?;
    Some(hertz_cost(pts, Some(layer), kept, p))
}

/// |d gamma1 / d c| of the tied Hertz fit at `p` (a = sqrt(gamma1 / c)),
/// mm²: the least-squares shift of gamma1 that takes up a change of the
/// curvature, -(J_g . J_c) / (J_g . J_g) over the kept markers, with
/// J_g = f + f_a a / 2 and J_c = -gamma1 f_a a / (2 c) (f_a = d f / d a,
/// -f' rho / a for Hertz's shape). Markers inside the
/// contact read gamma1 almost directly (small shift); far ones read gamma1 a
/// (gamma1 goes as c^(1/3) there).
fn tied_gamma1_per_curvature(
    pts: &[[f64; 3]],
    layer: Option<&SurfaceShape>,
    kept: &[bool],
    p: [f64; 4],
    c: f64,
) -> f64 {
    let [g, cx, cy, a] = p;
    let (mut gg, mut gc) = (0.0, 0.0);
    for (q, _) in pts.iter().zip(kept).filter(|(_, k)| **k) {
        let [f, _, fa] = field_shape_d(layer, (q[0] - cx).hypot(q[1] - cy), a);
        let jg = f + 0.5 * fa * a;
        let jc = -g * fa * a / (2.0 * c);
        gg += jg * jg;
        gc += jg * jc;
    }
    if gg > 0.0 { (gc / gg).abs() } else { 0.0 }
}

/// Covariance of the Hertz fit's parameters (gamma1, cx, cy, a) at `p`, from
/// its Jacobian, with the marker noise from the fit's residual `rms` over the
/// kept markers (held parameters have a unit diagonal and nothing else).
fn hertz_covariance(
    pts: &[[f64; 3]],
    layer: Option<&SurfaceShape>,
    kept: &[bool],
    p: [f64; 4],
    tie: Option<f64>,
    fixed_centre: bool,
    rms: f64,
) -> Option<Matrix4<f64>> {
    let m = kept.iter().filter(|&&b| b).count();
    let free = 4 - usize::from(tie.is_some()) - 2 * usize::from(fixed_centre);
    if m <= free {
        return None;
    }
    let mut field = HertzField { pts, layer, kept, tie, fixed_centre };
    let (jtj, _) = field.normal_equations(&Vector4::from(p))?;
    let cov = jtj.try_inverse()? * (rms * rms * m as f64 / (m - free) as f64);
    (cov[(0, 0)].is_finite() && cov[(0, 0)] >= 0.0).then_some(cov)
}

fn hertz_cost(pts: &[[f64; 3]], layer: Option<&SurfaceShape>, kept: &[bool], p: [f64; 4]) -> f64 {
    let [g, cx, cy, a] = p;
    pts.iter()
        .zip(kept)
        .filter(|(_, k)| **k)
        .map(|(q, _)| (q[2] - g * field_shape(layer, (q[0] - cx).hypot(q[1] - cy), a)).powi(2))
        .sum()
}

/// The Hertz field over the kept markers as a least-squares problem in
/// (gamma1, cx, cy, a); with `tie = Some(c)` the radius follows the depth,
/// a = sqrt(gamma1 / c), and only (gamma1, cx, cy) are free. Depth and radius
/// stay positive (other points are refused). With `fixed_centre` the
/// centre is held where it starts.
struct HertzField<'a> {
    pts: &'a [[f64; 3]],
    layer: Option<&'a SurfaceShape>,
    kept: &'a [bool],
    tie: Option<f64>,
    fixed_centre: bool,
}

impl Problem<U4> for HertzField<'_> {
    fn start(&mut self, x: &Vector4<f64>) -> Result<f64, LmError> {
        Ok(hertz_cost(self.pts, self.layer, self.kept, (*x).into()))
    }

    fn cost(&mut self, x: &Vector4<f64>) -> Option<f64> {
        (x[3] > 0.0 && x[0] > 0.0).then(|| hertz_cost(self.pts, self.layer, self.kept, (*x).into()))
    }

    fn normal_equations(&mut self, x: &Vector4<f64>) -> Option<NormalEquations<U4>> {
        let [g, cx, cy, a]: [f64; 4] = (*x).into();
        let mut jtj = Matrix4::<f64>::zeros();
        let mut jtr = Vector4::<f64>::zeros();
        for (q, _) in self.pts.iter().zip(self.kept).filter(|(_, k)| **k) {
            let (dx, dy) = (q[0] - cx, q[1] - cy);
            let r = dx.hypot(dy);
            let [f, fr, fa] = field_shape_d(self.layer, r, a);
            let (dcx, dcy) = if r > 0.0 { (-g * fr * dx / r, -g * fr * dy / r) } else { (0.0, 0.0) };
            // Tied: d(g f(r, a(g)))/dg = f + f_a a / 2 (a = sqrt(g / c)), and
            // a is no unknown.
            let j = match self.tie {
                None => Vector4::new(f, dcx, dcy, g * fa),
                Some(_) => Vector4::new(f + 0.5 * fa * a, dcx, dcy, 0.0),
            };
            jtj += j * j.transpose();
            jtr += j * (q[2] - g * f);
        }
        if self.tie.is_some() {
            jtj[(3, 3)] = 1.0;
        }
        if self.fixed_centre {
            for i in 1..3 {
                jtj.row_mut(i).fill(0.0);
                jtj.column_mut(i).fill(0.0);
                jtj[(i, i)] = 1.0;
                jtr[i] = 0.0;
            }
        }
        // The residuals are marker minus model: their Jacobian is -j.
        Some((jtj, -jtr))
    }

    fn project(&self, x: &mut Vector4<f64>) {
        if let Some(c) = self.tie {
            x[3] = (x[0] / c).sqrt();
        }
    }
}

/// Stopping rule of the Hertz field fit (parameters in mm, costs in mm²: the
/// tolerances are absolute below 1).
const HERTZ_LM: LmOptions =
    LmOptions { max_iterations: 500, cost_tolerance: 1e-16, step_tolerance: 1e-12, fd_step: 0.0, within_se: None };

/// Levenberg-Marquardt on the Hertz field (see [`HertzField`]) from `p`.
fn lm_hertz(
    pts: &[[f64; 3]],
    layer: Option<&SurfaceShape>,
    kept: &[bool],
    p: [f64; 4],
    tie: Option<f64>,
    fixed_centre: bool,
) -> Option<[f64; 4]> {
    let mut field = HertzField { pts, layer, kept, tie, fixed_centre };
    let out = lm::solve(&mut field, Vector4::from(p), &HERTZ_LM, &Strategy::FIELD).ok()?;
    out.x.iter().all(|v| v.is_finite()).then(|| out.x.into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadratic_maximum_of_a_known_paraboloid() {
        let q = Quadratic { c: [2.0, 0.0, 0.0, -1.0, 0.0, -1.0] };
        assert_eq!(q.maximum(), Some(([0.0, 0.0], 2.0)));
        // Shifted: w = 2 - (x - 0.3)^2 - (y + 0.2)^2.
        let mut pts = Vec::new();
        for i in -2..=2 {
            for j in -2..=2 {
                let (x, y) = (i as f64 * 0.5, j as f64 * 0.5);
                pts.push([x, y, 2.0 - (x - 0.3f64).powi(2) - (y + 0.2f64).powi(2)]);
            }
        }
        pts[7][2] += 0.3;
        let fit = fit_quadratic(&pts, true, 4.0, 1e-6).unwrap();
        assert!(!fit.kept[7] && fit.kept.iter().filter(|&&k| !k).count() == 1);
        let (c, w) = fit.surface.maximum().unwrap();
        assert!((c[0] - 0.3).abs() < 1e-10 && (c[1] + 0.2).abs() < 1e-10 && (w - 2.0).abs() < 1e-10);
        // A saddle has no maximum.
        assert!(Quadratic { c: [0.0, 0.0, 0.0, -1.0, 0.0, 1.0] }.maximum().is_none());
    }

    #[test]
    fn the_shapes_taken_together_are_the_shapes() {
        for rho in [0.0, 0.5, 1.0, 1.0 + 1e-9, 1.7, 12.0] {
            assert_eq!(hertz_and_punch_shapes(rho), (hertz_shape(rho), punch_shape(rho)), "rho {rho}");
            assert_eq!(hertz_shape_and_slope(rho), (hertz_shape(rho), hertz_slope(rho)), "rho {rho}");
        }
    }

    #[test]
    fn procrustes_recovers_a_finite_rotation_and_drops_an_outlier() {
        let centre = [0.4, -0.3];
        let theta = 5f64.to_radians();
        let (s, c) = theta.sin_cos();
        let mut p = Vec::new();
        let mut q = Vec::new();
        for i in -2..=2 {
            for j in -2..=2 {
                let (x, y) = (i as f64, j as f64);
                let (dx, dy) = (x - centre[0], y - centre[1]);
                p.push([x, y]);
                q.push([centre[0] + c * dx - s * dy, centre[1] + s * dx + c * dy]);
            }
        }
        q[3][0] += 0.2;
        let fit = fit_rotation(&p, &q, centre, 4.0, 1e-6).unwrap();
        assert!((fit.theta - theta).abs() < 1e-12, "{}", fit.theta);
        assert!(!fit.kept[3] && fit.kept.iter().filter(|&&k| !k).count() == 1);
    }
}

/// [`hertz_shape`] and [`punch_shape`] at `rho` together (one arcsine: the
/// punch fit evaluates both at every marker several hundred times a frame).
fn hertz_and_punch_shapes(rho: f64) -> (f64, f64) {
    if rho <= 1.0 {
        return (1.0 - 0.5 * rho * rho, 1.0);
    }
    let s = (1.0 / rho).asin();
    (((2.0 - rho * rho) * s + (rho * rho - 1.0).sqrt()) / std::f64::consts::PI, std::f64::consts::FRAC_2_PI * s)
}

/// Normalised flat-punch normal field w(r) / w(0) at rho = r / a: 1 inside,
/// (2/pi) asin(1/rho) outside (docs/sensing.md, "Adhesive contacts").
pub fn punch_shape(rho: f64) -> f64 {
    if rho <= 1.0 { 1.0 } else { std::f64::consts::FRAC_2_PI * (1.0 / rho).asin() }
}

/// An adhesive (JKR) contact fitted at a known centre with a known
/// curvature: what [`fit_tied_punch`] found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PunchFit {
    /// Peak depth, mm (the Hertz part c a^2 plus the punch part).
    pub gamma1: f64,
    /// Contact radius, mm.
    pub radius: f64,
    /// The punch part of gamma1, mm (<= 0).
    pub punch: f64,
    /// Sum of squared residuals over the kept markers, mm^2.
    pub sse: f64,
    /// Standard error of gamma1 for unit marker noise (times the noise: mm).
    pub gamma1_sd_per_noise: f64,
}

/// The JKR field at a known centre with a known curvature c: Hertz's field
/// of depth c a^2 plus a flat punch's of depth p = gamma1 - c a^2 at the same
/// radius a. Inside the contact it is gamma1 - c r^2 / 2 whatever p is; the
/// punch shows outside, where the field falls off more steeply than
/// Hertz's. Two unknowns, gamma1 and p (a = sqrt((gamma1 - p) / c)); p = 0
/// is the tied Hertz fit. Damped Gauss-Newton from p = 0 and from a punch of
/// a third of the depth, p held <= 0 (an adhesive edge pulls; it never
/// pushes). `None` when degenerate.
///
/// On a declared gel layer (`layer`) the Hertz part has the layer's shape
/// ([`field_shape`]).
pub fn fit_tied_punch(
    pts: &[[f64; 3]],
    layer: Option<&SurfaceShape>,
    kept: &[bool],
    centre: [f64; 2],
    c: f64,
    gamma1: f64,
) -> Option<PunchFit> {
    if !(c > 0.0 && gamma1 > 0.0) {
        return None;
    }
    // The model at (gamma1, punch, r), one monomorphised fit per field: the
    // half-space's is the hot path of a tacky gel's frames.
    match layer {
        None => tied_punch_with(pts, kept, centre, c, gamma1, |g: f64, p: f64, r: f64| {
            let h = g - p;
            let (hertz, punch) = hertz_and_punch_shapes(r * (c / h).sqrt());
            h * hertz + p * punch
        }),
        Some(l) => tied_punch_with(pts, kept, centre, c, gamma1, |g: f64, p: f64, r: f64| {
            let h = g - p;
            let a = (h / c).sqrt();
            let (hertz, punch) = hertz_and_punch_shapes(r / a);
            h * (hertz + l.departure(r, a)) + p * punch
        }),
    }
}

/// [`fit_tied_punch`] with its field `model(gamma1, punch, r)`.
fn tied_punch_with(
    pts: &[[f64; 3]],
    kept: &[bool],
    centre: [f64; 2],
    c: f64,
    gamma1: f64,
    model: impl Fn(f64, f64, f64) -> f64,
) -> Option<PunchFit> {
    let radii: Vec<(f64, f64)> = pts
        .iter()
        .zip(kept)
        .filter(|(_, k)| **k)
        .map(|(q, _)| ((q[0] - centre[0]).hypot(q[1] - centre[1]), q[2]))
        .collect();
    if radii.len() < 4 {
        return None;
    }
    let sse = |g: f64, p: f64| radii.iter().map(|&(r, z)| (z - model(g, p, r)).powi(2)).sum::<f64>();
    let normal = |g: f64, p: f64| -> (Matrix2<f64>, Vector2<f64>) {
        let h = 1e-7 * g.abs().max(1e-3);
        let mut jtj = Matrix2::zeros();
        let mut jtr = Vector2::zeros();
        for &(r, z) in &radii {
            let jg = (model(g + h, p, r) - model(g - h, p, r)) / (2.0 * h);
            let jp = (model(g, p + h, r) - model(g, p - h, r)) / (2.0 * h);
            let j = Vector2::new(jg, jp);
            jtj += j * j.transpose();
            jtr += j * (z - model(g, p, r));
        }
        (jtj, jtr)
    };
    let descend = |g0: f64, p0: f64| -> Option<(f64, f64, f64)> {
        let (mut g, mut p) = (g0, p0);
        let mut cost = sse(g, p);
        let mut lambda = 1e-3;
        for _ in 0..40 {
            let (jtj, jtr) = normal(g, p);
            let mut damped = jtj;
            damped[(0, 0)] *= 1.0 + lambda;
            damped[(1, 1)] *= 1.0 + lambda;
            let step = damped.try_inverse()? * jtr;
            let (g1, p1) = (g + step[0], (p + step[1]).min(0.0));
            let c1 = if g1 > 0.0 && g1 - p1 > 0.0 { sse(g1, p1) } else { f64::INFINITY };
            if c1 < cost {
                let done = cost - c1 <= 1e-10 * cost.max(1e-18);
                (g, p, cost) = (g1, p1, c1);
                lambda = (lambda * 0.3).max(1e-9);
                if done {
                    break;
                }
            } else {
                lambda *= 10.0;
                if lambda > 1e8 {
                    break;
                }
            }
        }
        Some((g, p, cost))
    };
    // From a punch of nothing up to twice the depth: a JKR contact under a
    // pitch pulls by more than it presses (p = -1.4 gamma1 at a = 0.85 mm on
    // the default pair at 500 mJ/m²), a valley the small starts do not reach.
    let (g, p, cost) = [0.0, -0.3, -1.0, -2.0]
        .map(|k| descend(gamma1, k * gamma1))
        .into_iter()
        .flatten()
        .min_by(|x, y| x.2.total_cmp(&y.2))?;
    let radius = ((g - p) / c).sqrt();
    let sd = normal(g, p).0.try_inverse()?[(0, 0)].sqrt();
    (g.is_finite() && radius.is_finite() && sd.is_finite()).then_some(PunchFit {
        gamma1: g,
        radius,
        punch: p,
        sse: cost,
        gamma1_sd_per_noise: sd,
    })
}
