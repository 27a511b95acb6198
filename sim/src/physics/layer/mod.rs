//! Contact with an elastomer layer of thickness h on a rigid base, exact within
//! linear elasticity (docs/physics.md, "Layered contact").
//!
//! Normal: the contact pressure is written through an auxiliary function g on
//! [0, a], p̄(ξ) = ∫_0^a g(t) cos(ξt) dt. The half-space part of the gap
//! condition inverts in closed form (Abel), leaving a Fredholm equation of the
//! second kind for the layer's correction,
//!   g(t) - λ ∫_0^a g(s) L(s, t) ds = (E*/π)(δ - t²/R*),   λ = (2/π) E*/E1*,
//!   L(s, t) = (1/2h) [C((s-t)/h) + C((s+t)/h)],
//! solved by Nyström on Gauss–Legendre nodes; a smooth edge, g(a) = 0, fixes δ
//! for a given contact radius a. Then F = 2π ∫ g, and the axis deflections are
//! gamma1 = π g(0)/E1* - (2/E1*) ∫ g(s) C(s/h)/h ds and gamma2 = π g(0)/E2*.
//! The indenter stays a half-space in the gap condition, and the paper's
//! corrections of the axis values (Yoffe on gamma2, Tatara on both) are applied
//! on top, so h -> infinity is the paper's model (docs/physics.md, Eqs. 2-5, 20).
//!
//! Torsion: a patch of radius a bonded to the indenter and rotated by θ. With
//! τ̄₁(ξ) = ∫_0^a ψ(t) sin(ξt) dt the same steps give
//!   ψ(t) - (2/π) ∫_0^a ψ(s) L_t(s, t) ds = t,  L_t = (1/2h)[S((s-t)/h) - S((s+t)/h)],
//! and the torque T = 16 G θ ∫ t ψ(t) dt (Reissner–Sagoci, 16/3 G a³ θ, when h -> infinity).

mod curve;
pub mod kernel;

pub use curve::LayeredContact;

use std::f64::consts::PI;

use nalgebra::{DMatrix, DVector};

use super::YOFFE;
use super::normal::{NormalError, NormalState};
use super::params::{ContactPair, Layer, ParamError};
use super::quadrature::{UniformTable, gauss_legendre_on};

/// Nyström nodes for a contact of radius a on a layer of thickness h: the
/// kernel's width is ~h, so more nodes as a/h grows.
fn nodes_for(a_over_h: f64) -> usize {
    (14.0 + 6.0 * a_over_h).ceil().min(96.0) as usize
}

/// The bodies' shape in the gap condition.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Profile {
    /// r²/(2R*), Hertz's approximation and the paper's.
    #[default]
    Paraboloid,
    /// R - sqrt(R² - r²) for each curved body: exact spheres (contact radius < R).
    Sphere,
}

/// The normal contact of an elastic sphere on an elastomer layer.
#[derive(Debug, Clone)]
pub struct LayeredNormal {
    h_mm: f64,
    /// Plane-strain moduli E1*, E2* and the composite E*, MPa.
    e1s: f64,
    e2s: f64,
    es: f64,
    r_star: f64,
    profile: Profile,
    /// Radii of the curved bodies (finite ones), for the exact sphere profile.
    radii: Vec<f64>,
    b1: f64,
    b2: f64,
    /// C(y) of the layer's deficit, y in units of h.
    c: UniformTable,
    /// Largest contact radius the table covers, mm.
    a_max_mm: f64,
}

impl LayeredNormal {
    /// The model for `pair` on `layer`, tabulated for contact radii up to `a_max_mm`.
    /// nu1 may be 0.5 here (an incompressible gel).
    pub fn new(pair: &ContactPair, layer: &Layer, a_max_mm: f64) -> Result<Self, ParamError> {
        Self::with_profile(pair, layer, a_max_mm, Profile::Paraboloid)
    }

    /// As [`Self::new`] with the bodies' shape in the gap chosen; with exact
    /// spheres the contact radius stays below the smaller radius.
    pub fn with_profile(
        pair: &ContactPair,
        layer: &Layer,
        a_max_mm: f64,
        profile: Profile,
    ) -> Result<Self, ParamError> {
        layer.validate()?;
        pair.indenter.validate("indenter")?;
        let el = pair.elastomer;
        if !(el.e_mpa.is_finite() && el.e_mpa > 0.0) {
            return Err(ParamError::Modulus { what: "elastomer", value: el.e_mpa });
        }
        if !(el.nu > 0.0 && el.nu <= 0.5) {
            return Err(ParamError::Poisson { what: "elastomer", value: el.nu });
        }
        let h = layer.thickness_mm;
        let (base, nu) = (layer.base, el.nu);
        let radii: Vec<f64> = [el.r_mm, pair.indenter.r_mm].into_iter().filter(|r| r.is_finite()).collect();
        let mut a_max_mm = a_max_mm.max(1e-3);
        if profile == Profile::Sphere {
            a_max_mm = radii.iter().fold(a_max_mm, |m, r| m.min(0.995 * r));
        }
        let c = kernel::cosine_table(|x| kernel::normal_deficit(base, nu, x), 2.0 * a_max_mm / h);
        let e1s = el.plane_strain_mpa();
        let e2s = pair.indenter.plane_strain_mpa();
        Ok(Self {
            h_mm: h,
            e1s,
            e2s,
            es: 1.0 / (1.0 / e1s + 1.0 / e2s),
            r_star: pair.composite_radius_mm(),
            profile,
            radii,
            b1: el.tatara_mm_per_n(),
            b2: pair.indenter.tatara_mm_per_n(),
            c,
            a_max_mm,
        })
    }

    pub fn max_contact_radius_mm(&self) -> f64 {
        self.a_max_mm
    }

    /// The gap's term in the Fredholm equation's right-hand side: the Abel
    /// transform of the profile, (π/2) A[f](t) — t²/R* for paraboloids,
    /// Σ (t/2) ln((R+t)/(R-t)) for spheres.
    fn gap(&self, t: f64) -> f64 {
        match self.profile {
            Profile::Paraboloid => t * t / self.r_star,
            Profile::Sphere => self.radii.iter().map(|r| 0.5 * t * ((r + t) / (r - t)).ln()).sum(),
        }
    }

    fn l(&self, s: f64, t: f64) -> f64 {
        let h = self.h_mm;
        (self.c.eval((s - t).abs() / h) + self.c.eval((s + t) / h)) / (2.0 * h)
    }

    /// Every quantity at contact radius `a_mm` (one Nyström solve).
    pub fn at_contact_radius(&self, a_mm: f64) -> NormalState {
        self.at_contact_radius_with(a_mm, nodes_for(a_mm / self.h_mm))
    }

    /// As [`Self::at_contact_radius`] with `n` Nyström nodes (for convergence checks).
    pub fn at_contact_radius_with(&self, a_mm: f64, n: usize) -> NormalState {
        self.pressure_at(a_mm, n).map_or(NormalState::NONE, |p| p.state)
    }

    /// The gel surface's deflection (mm, towards the base) on the axis and at
    /// each radius of `r_mm` outside a contact of radius `a_mm` (inside, the
    /// surface follows the indenter): the layer's response to the contact
    /// pressure, without Tatara's correction of the axis value,
    ///   w(r) = (2/E1*) [∫_0^a g(t) / sqrt(r² - t²) dt - ∫_0^a g(t) M(r, t) dt],
    /// M(r, t) = ∫ (1 - K(ξh)) cos(ξt) J0(ξr) dξ = (2/π) ∫_0^{π/2} L(t, r sin φ) dφ
    /// (J0 by Poisson's integral): the half-space's Boussinesq field less the
    /// layer's deficit. A radius inside the contact gives NaN; `None` without
    /// contact. The layer's table reaches (a + r)/h = 2 `a_max_mm`/h: further
    /// out the deficit is held at its last tabulated value (build the model
    /// with `a_max_mm` at least half the largest a + r).
    pub fn surface_deflection_mm(&self, a_mm: f64, r_mm: &[f64]) -> Option<(f64, Vec<f64>)> {
        let p = self.pressure_at(a_mm, nodes_for(a_mm / self.h_mm))?;
        let (phi, wphi) = gauss_legendre_on(48, 0.0, PI / 2.0);
        let at = r_mm
            .iter()
            .map(|&r| {
                if r < p.a_mm * (1.0 - 1e-12) || !r.is_finite() {
                    return f64::NAN;
                }
                let boussinesq: f64 =
                    p.nodes.iter().zip(&p.weights).zip(&p.g).map(|((t, w), g)| w * g / (r * r - t * t).sqrt()).sum();
                let deficit: f64 = p
                    .nodes
                    .iter()
                    .zip(&p.weights)
                    .zip(&p.g)
                    .map(|((&t, w), g)| {
                        let m: f64 =
                            phi.iter().zip(&wphi).map(|(f, wf)| wf * self.l(t, r * f.sin())).sum::<f64>() * 2.0 / PI;
                        w * g * m
                    })
                    .sum();
                2.0 / self.e1s * (boussinesq - deficit)
            })
            .collect();
        Some((p.axis_mm, at))
    }

    /// The Nyström solution at contact radius `a_mm` with `n` nodes: g on
    /// the nodes and every quantity of the state; `None` without contact.
    fn pressure_at(&self, a_mm: f64, n: usize) -> Option<Pressure> {
        let a = a_mm.clamp(0.0, self.a_max_mm);
        if a <= 0.0 || n == 0 {
            return None;
        }
        let (s, w) = gauss_legendre_on(n, 0.0, a);
        let lam = 2.0 / PI * self.es / self.e1s;
        let mut m = DMatrix::identity(n, n);
        for i in 0..n {
            for j in 0..=i {
                // L is symmetric: evaluate each pair once.
                let l = lam * self.l(s[j], s[i]);
                m[(i, j)] -= w[j] * l;
                if i != j {
                    m[(j, i)] -= w[i] * l;
                }
            }
        }
        // g = (E*/π)(δ g_c + g_q): unit constant and -t²/R* right-hand sides.
        let rhs = DMatrix::from_fn(n, 2, |i, k| if k == 0 { 1.0 } else { -self.gap(s[i]) });
        let sol = m.lu().solve(&rhs)?;
        // Nyström interpolation of both solutions at t = a and t = 0.
        let row_a: Vec<f64> = (0..n).map(|j| lam * w[j] * self.l(s[j], a)).collect();
        let row_0: Vec<f64> = (0..n).map(|j| lam * w[j] * self.l(s[j], 0.0)).collect();
        let at = |row: &[f64], k: usize, base: f64| base + (0..n).map(|j| row[j] * sol[(j, k)]).sum::<f64>();
        let (gc_a, gq_a) = (at(&row_a, 0, 1.0), at(&row_a, 1, -self.gap(a)));
        let delta_h = -gq_a / gc_a;
        let scale = self.es / PI;
        let g: DVector<f64> = DVector::from_fn(n, |j, _| scale * (delta_h * sol[(j, 0)] + sol[(j, 1)]));
        let g0 = scale * (delta_h * at(&row_0, 0, 1.0) + at(&row_0, 1, 0.0));
        let force = 2.0 * PI * (0..n).map(|j| w[j] * g[j]).sum::<f64>();
        let layer_part: f64 = (0..n).map(|j| w[j] * g[j] * self.c.eval(s[j] / self.h_mm) / self.h_mm).sum();
        let axis_mm = PI * g0 / self.e1s - 2.0 / self.e1s * layer_part;
        let gamma1 = axis_mm - self.b1 * force;
        let gamma2 = YOFFE * PI * g0 / self.e2s - self.b2 * force;
        let state = NormalState {
            delta_mm: gamma1 + gamma2,
            gamma1_mm: gamma1,
            gamma2_mm: gamma2,
            force_n: force,
            contact_radius_mm: a,
        };
        Some(Pressure { a_mm: a, nodes: s, weights: w, g: g.iter().copied().collect(), axis_mm, state })
    }

    /// The state at stage approach `delta_mm` (gamma1 + gamma2), by bisection-guarded
    /// secant on the contact radius.
    pub fn solve(&self, delta_mm: f64) -> Result<NormalState, NormalError> {
        self.solve_by(delta_mm, |st| st.delta_mm)
    }

    /// The state at which the indenter's deformation is `gamma2_mm` (torsion depth).
    pub fn solve_for_gamma2(&self, gamma2_mm: f64) -> Result<NormalState, NormalError> {
        self.solve_by(gamma2_mm, |st| st.gamma2_mm)
    }

    fn solve_by(&self, target: f64, f: impl Fn(&NormalState) -> f64) -> Result<NormalState, NormalError> {
        if !target.is_finite() {
            return Err(NormalError::NotFinite { delta_mm: target });
        }
        if target <= 0.0 {
            return Ok(NormalState::NONE);
        }
        // sqrt(f) is nearly linear in a (f ~ a²/R): secant on it from the origin
        // and a Hertz-like first guess, kept inside a bracket.
        let phi = |st: &NormalState| f(st).max(0.0).sqrt() - target.sqrt();
        let (mut lo, mut hi, mut hi_known) = (0.0, self.a_max_mm, false);
        let (mut a_prev, mut p_prev) = (0.0, -target.sqrt());
        let mut a = (target * self.r_star).sqrt().min(self.a_max_mm);
        let mut best = NormalState::NONE;
        for _ in 0..60 {
            let st = self.at_contact_radius(a);
            let p = phi(&st);
            best = st;
            // 1e-11 of sqrt(target): 2e-11 of the approach, a picometre at a
            // millimetre, far under the 1e-4 the layer is checked to.
            if p.abs() <= 1e-11 * target.sqrt() || hi - lo < 1e-14 * self.a_max_mm {
                return Ok(best);
            }
            if p < 0.0 {
                lo = a;
            } else {
                (hi, hi_known) = (a, true);
            }
            if !hi_known && a >= self.a_max_mm {
                break;
            }
            // Secant through the last two iterates; bisection when it leaves the bracket.
            let next = a - p * (a - a_prev) / (p - p_prev);
            (a_prev, p_prev) = (a, p);
            a = if next > lo && next < hi {
                next
            } else if hi_known {
                0.5 * (lo + hi)
            } else {
                (2.0 * a).min(hi)
            };
        }
        let phi_hi = if hi_known { 0.0 } else { f64::NAN };
        if phi_hi.is_nan() {
            let top = self.at_contact_radius(self.a_max_mm);
            if f(&top) < target {
                return Err(NormalError::BeyondModel { delta_mm: target, limit_mm: f(&top) });
            }
        }
        Ok(best)
    }
}

/// A contact's pressure as the layer solver represents it: g on the
/// Gauss–Legendre nodes of [0, a] (with their weights), and the state.
struct Pressure {
    a_mm: f64,
    nodes: Vec<f64>,
    weights: Vec<f64>,
    g: Vec<f64>,
    /// The gel's deflection on the axis without Tatara's correction, mm.
    axis_mm: f64,
    state: NormalState,
}

/// Torsion of a bonded patch on a layer bonded to its base.
#[derive(Debug, Clone)]
pub struct LayeredTorsion {
    h_mm: f64,
    s: UniformTable,
    a_max_mm: f64,
}

impl LayeredTorsion {
    /// Tabulated for contact radii up to `a_max_mm`. The base counts as bonded
    /// for torsion: a gel free to slide on its window would not hold a twist at all.
    pub fn new(layer: &Layer, a_max_mm: f64) -> Result<Self, ParamError> {
        layer.validate()?;
        let h = layer.thickness_mm;
        let a_max_mm = a_max_mm.max(1e-3);
        Ok(Self { h_mm: h, s: kernel::cosine_table(kernel::torsion_deficit, 2.0 * a_max_mm / h), a_max_mm })
    }

    /// T_layer / T_half-space for a patch of radius `a_mm` (>= 1; the base stiffens).
    pub fn stiffness_factor(&self, a_mm: f64) -> f64 {
        self.stiffness_factor_with(a_mm, nodes_for(a_mm / self.h_mm))
    }

    /// As [`Self::stiffness_factor`] with `n` Nyström nodes.
    pub fn stiffness_factor_with(&self, a_mm: f64, n: usize) -> f64 {
        let a = a_mm.clamp(0.0, self.a_max_mm);
        if a <= 0.0 || n == 0 {
            return 1.0;
        }
        let h = self.h_mm;
        let lt = |s: f64, t: f64| (self.s.eval((s - t).abs() / h) - self.s.eval((s + t) / h)) / (2.0 * h);
        let (s, w) = gauss_legendre_on(n, 0.0, a);
        let m = DMatrix::from_fn(n, n, |i, j| if i == j { 1.0 } else { 0.0 } - 2.0 / PI * w[j] * lt(s[j], s[i]));
        let rhs = DVector::from_fn(n, |i, _| s[i]);
        let Some(psi) = m.lu().solve(&rhs) else {
            return f64::NAN;
        };
        // T / (G θ) = 16 ∫ t ψ dt; the half-space's is 16 a³/3.
        let t_over_g = 16.0 * (0..n).map(|j| w[j] * s[j] * psi[j]).sum::<f64>();
        t_over_g / (16.0 * a * a * a / 3.0)
    }

    /// Torsional stiffness T/θ of the layer under a patch of radius `a_mm`, N·mm/rad.
    pub fn stiffness_nmm_per_rad(&self, shear_mpa: f64, a_mm: f64) -> f64 {
        16.0 / 3.0 * shear_mpa * a_mm.powi(3) * self.stiffness_factor(a_mm)
    }
}

#[cfg(test)]
mod tests;
