//! The marker field a Tac3D-class sensor reports for a Hertzian contact with a
//! twist, on a domed 20 x 20 marker grid, with the sensor's imperfections
//! (marker noise, outlier markers, lost frames, exact zeros without contact).
//!
//! Surface fields (Johnson, *Contact Mechanics*, 1985, Eqs. 3.41-3.42; Jäger
//! 1995 for the twisted disc), with r the in-plane distance from the contact
//! centre, a the contact radius and rho = r / a:
//!
//! * normal, inside (rho <= 1):  w = gamma1 * (1 - rho^2 / 2)
//! * normal, outside (rho > 1):  w = gamma1 * ((2 - rho^2) asin(1/rho) + sqrt(rho^2 - 1)) / pi
//!
//!   Both come from the Hertz pressure p0 sqrt(1 - rho^2); the common factor
//!   (1 - nu^2) pi p0 a / (2E) is the centre value, so w(0) = gamma1 exactly,
//!   w(a) = gamma1 / 2 from both sides and the slope is continuous there.
//! * radial, inside:  u_r = -gamma1 k (a/r) (1 - (1 - rho^2)^{3/2}),
//!   outside: u_r = -gamma1 k (a/r), with k = 2(1 - 2 nu) / (3 pi (1 - nu))
//!   (the same pressure; zero for an incompressible elastomer, nu = 0.5).
//! * twist (full stick, rigid rotation theta of the contact disc):
//!   inside u_phi = theta r, outside u_phi = (2 theta / pi) (r asin(a/r) - a sqrt(1 - a^2/r^2)),
//!   the disc field of docs/physics.md 2.7 with s = a. It is applied as a finite
//!   rotation of each ring by psi(r) = u_phi / r, so the stuck disc turns
//!   rigidly by exactly theta even at several degrees (the linear field would
//!   read as atan(theta), 0.01 deg low at 5 deg).
//!
//! The sensor reports the normal field as dz = -w (z is the outward normal, so
//! pressing gives negative dz). Displacements are applied in the sensor's
//! global frame at the projected (x, y) of each marker: the dome (R ~ 33 mm)
//! tilts the local normal by at most ~17 degrees at the grid corners, where
//! the field is already small.

use std::sync::Arc;

use devices::sensor::SensorFrame;

use super::shape::SurfaceShape;

use crate::rng::Rng;

/// What the elastomer under the indenter is doing at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactState {
    /// Contact centre in the sensor's marker coordinates, mm.
    pub center_mm: [f64; 2],
    /// Peak normal displacement of the elastomer (into it, > 0), mm.
    pub gamma1_mm: f64,
    /// Contact radius, mm (> 0).
    pub contact_radius_mm: f64,
    /// Rigid rotation of the stuck contact disc about +z (counter-clockwise
    /// seen from outside the elastomer), rad.
    pub theta1_rad: f64,
    /// Poisson's ratio of the elastomer; sets the in-plane radial field of the
    /// normal contact (0.5: none).
    pub nu1: f64,
    /// The flat-punch part of `gamma1_mm` (mm, <= 0 for an adhesive contact,
    /// 0 for Hertz): a JKR contact is Hertz's field for its radius plus a
    /// rigid punch's, uniform inside the contact (see [`punch_shape`]).
    pub punch_mm: f64,
    /// The indenter's and the elastomer's radii, mm (infinite: a paraboloid,
    /// Hertz's idealisation). Inside the contact the surface follows the
    /// spheres, which sag below Hertz's paraboloid by [`sphere_excess_mm`];
    /// outside, that sag at the edge fades as Hertz's field does.
    pub indenter_radius_mm: f64,
    pub elastomer_radius_mm: f64,
    /// The sensor's depth gain (1: exact), which scales the spheres' sag as
    /// it scales every depth it reports (`gamma1_mm` already carries it).
    pub depth_gain: f64,
}

/// How far the surface of a contact of radius `contact_radius_mm` between
/// spheres of radii `indenter_r_mm` and `elastomer_r_mm` lies below Hertz's
/// field (whose paraboloids osculate the spheres) at `r_mm` from its centre,
/// mm: inside, the surface follows the spheres ([`sphere_excess_mm`] of
/// each); outside, the sag at the edge fades as Hertz's field does
/// (continuous at the edge; docs/sensing.md, "The spheres inside a wide
/// contact").
pub fn spheres_sag_mm(r_mm: f64, contact_radius_mm: f64, indenter_r_mm: f64, elastomer_r_mm: f64) -> f64 {
    let at = |r: f64| sphere_excess_mm(r, indenter_r_mm) + sphere_excess_mm(r, elastomer_r_mm);
    let a = contact_radius_mm;
    if r_mm <= a {
        at(r_mm)
    } else if a > 0.0 {
        at(a) * normal_shape(r_mm / a) / normal_shape(1.0)
    } else {
        0.0
    }
}

/// How far a sphere of radius `radius_mm` sags below its osculating
/// paraboloid at `r_mm` from its axis, mm: R − sqrt(R² − r²) − r²/2R (0 for
/// a flat body, and held at the sphere's equator beyond it).
pub fn sphere_excess_mm(r_mm: f64, radius_mm: f64) -> f64 {
    if !(radius_mm.is_finite() && radius_mm > 0.0) {
        return 0.0;
    }
    let q = (r_mm * r_mm).min(radius_mm * radius_mm);
    // Written without the cancellation: q² / (2R (R + sqrt(R² − q))²).
    q * q / (2.0 * radius_mm * (radius_mm + (radius_mm * radius_mm - q).sqrt()).powi(2))
}

impl ContactState {
    /// A contact on an incompressible elastomer (no radial in-plane field).
    pub fn new(center_mm: [f64; 2], gamma1_mm: f64, contact_radius_mm: f64, theta1_rad: f64) -> Self {
        Self {
            center_mm,
            gamma1_mm,
            contact_radius_mm,
            theta1_rad,
            nu1: 0.5,
            punch_mm: 0.0,
            indenter_radius_mm: f64::INFINITY,
            elastomer_radius_mm: f64::INFINITY,
            depth_gain: 1.0,
        }
    }

    /// A sensor whose depth readings are scaled by `gain` (see `depth_gain`).
    pub fn with_depth_gain(mut self, gain: f64) -> Self {
        self.depth_gain = gain;
        self
    }

    /// The contact of an indenter of radius `indenter_r_mm` on an elastomer
    /// of radius `elastomer_r_mm` (infinite when flat): their spheres' sag
    /// inside the contact is in the field.
    pub fn with_spheres(mut self, indenter_r_mm: f64, elastomer_r_mm: f64) -> Self {
        self.indenter_radius_mm = indenter_r_mm;
        self.elastomer_radius_mm = elastomer_r_mm;
        self
    }

    fn sag_mm(&self, r_mm: f64) -> f64 {
        self.depth_gain
            * spheres_sag_mm(r_mm, self.contact_radius_mm, self.indenter_radius_mm, self.elastomer_radius_mm)
    }

    /// The same peak depth made of a Hertz field of depth `gamma1_mm - punch_mm`
    /// and a flat punch of depth `punch_mm` at the same radius (JKR).
    pub fn with_punch(mut self, punch_mm: f64) -> Self {
        self.punch_mm = punch_mm;
        self
    }

    pub fn with_nu1(mut self, nu1: f64) -> Self {
        self.nu1 = nu1;
        self
    }

    /// Displacement `[dx, dy, dz]` (mm) of the surface point at `(x, y)`.
    pub fn displacement_at(&self, x: f64, y: f64) -> [f64; 3] {
        self.displacement_on(x, y, None)
    }

    /// [`ContactState::displacement_at`] on a declared gel layer whose
    /// normal field departs from Hertz's as `layer` says (its Hertz part
    /// takes the departure; docs/sensing.md, "On a layer").
    pub fn displacement_on(&self, x: f64, y: f64, layer: Option<&SurfaceShape>) -> [f64; 3] {
        let a = self.contact_radius_mm;
        if a.is_nan() || a <= 0.0 {
            return [0.0; 3];
        }
        let dx = x - self.center_mm[0];
        let dy = y - self.center_mm[1];
        let r = dx.hypot(dy);
        let rho = r / a;
        let (hertz, punch) = (self.gamma1_mm - self.punch_mm, self.punch_mm);
        let departure = layer.map_or(0.0, |l| l.departure(r, a));
        let w = hertz * (normal_shape(rho) + departure) + punch * punch_shape(rho) - self.sag_mm(r);
        // In-plane: radial and twist components along e_r = (dx, dy)/r and
        // e_phi = (-dy, dx)/r; both vanish at the centre.
        if r == 0.0 {
            return [0.0, 0.0, -w];
        }
        // The ring of radius r first contracts radially (Hertz, u_r), then
        // turns rigidly by psi(r) = u_phi(r) / r: exactly theta inside the
        // stuck disc (a finite rigid rotation, which the twist sweep's several
        // degrees need), the linear elastic field outside. Contracting before
        // turning keeps the stuck disc a rigidly rotated copy of the pressed
        // one, so its rotation is theta whatever nu is.
        let psi = self.theta1_rad * a * twist_shape(rho) / r;
        let (s, c) = psi.sin_cos();
        let u_r = -hertz * radial_coefficient(self.nu1) * radial_shape(rho)
            - punch * punch_radial_coefficient(self.nu1) * punch_radial_shape(rho);
        let scale = 1.0 + u_r / r;
        let (px, py) = (dx * scale, dy * scale);
        [c * px - s * py - dx, s * px + c * py - dy, -w]
    }
}

/// Normalised Hertz normal displacement w(r) / w(0) at rho = r / a.
pub fn normal_shape(rho: f64) -> f64 {
    if rho <= 1.0 {
        1.0 - 0.5 * rho * rho
    } else {
        ((2.0 - rho * rho) * (1.0 / rho).asin() + (rho * rho - 1.0).sqrt()) / std::f64::consts::PI
    }
}

/// Normalised flat-punch normal displacement w(r) / w(0) at rho = r / a:
/// 1 inside the contact (a rigid flat face), (2/pi) asin(1/rho) outside
/// (Boussinesq's punch, Johnson 1985 Eq. 3.38). Continuous at the edge, where
/// the outside field leaves with an infinite slope (the punch's edge singularity).
pub fn punch_shape(rho: f64) -> f64 {
    if rho <= 1.0 { 1.0 } else { std::f64::consts::FRAC_2_PI * (1.0 / rho).asin() }
}

/// Normalised flat-punch radial field |u_r| / (w(0) k_p) at rho = r / a
/// (> 0 inward for a pressing punch): (1 - sqrt(1 - rho^2)) / rho inside,
/// 1 / rho outside, with k_p from [`punch_radial_coefficient`].
pub fn punch_radial_shape(rho: f64) -> f64 {
    if rho <= 0.0 {
        0.0
    } else if rho <= 1.0 {
        (1.0 - (1.0 - rho * rho).sqrt()) / rho
    } else {
        1.0 / rho
    }
}

/// k_p = (1 - 2 nu) / (pi (1 - nu)): the punch's radial to normal field scale
/// (its load P gives w(0) = P (1 - nu^2) / (2 a E) and, outside, u_r =
/// (1 - 2 nu)(1 + nu) P / (2 pi E r)).
pub fn punch_radial_coefficient(nu: f64) -> f64 {
    if nu >= 0.5 || nu <= -1.0 {
        return 0.0;
    }
    (1.0 - 2.0 * nu) / (std::f64::consts::PI * (1.0 - nu))
}

/// Normalised twist field u_phi / (theta a) at rho = r / a (rigid disc in full stick).
pub fn twist_shape(rho: f64) -> f64 {
    if rho <= 1.0 {
        rho
    } else {
        let inv = 1.0 / rho;
        std::f64::consts::FRAC_2_PI * (rho * inv.asin() - (1.0 - inv * inv).sqrt())
    }
}

/// Normalised Hertz radial field |u_r| / (gamma1 k) at rho = r / a (> 0 means inward).
pub fn radial_shape(rho: f64) -> f64 {
    if rho <= 0.0 {
        0.0
    } else if rho <= 1.0 {
        (1.0 - (1.0 - rho * rho).powf(1.5)) / rho
    } else {
        1.0 / rho
    }
}

/// k = 2(1 - 2 nu) / (3 pi (1 - nu)): ratio of the radial to the normal field scale.
pub fn radial_coefficient(nu: f64) -> f64 {
    if nu >= 0.5 || nu <= -1.0 {
        return 0.0;
    }
    2.0 * (1.0 - 2.0 * nu) / (3.0 * std::f64::consts::PI * (1.0 - nu))
}

/// Reference positions of the sensor's markers.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerGrid {
    pub positions: Vec<[f64; 3]>,
}

impl MarkerGrid {
    /// `nx` x `ny` markers at `pitch_mm`, centred on the origin, on a dome of
    /// radius `dome_radius_mm` whose apex is at z = 0 (z < 0 away from it).
    /// Row-major: y outer, x inner. `dome_radius_mm` = infinity gives a flat grid.
    pub fn dome(nx: usize, ny: usize, pitch_mm: f64, dome_radius_mm: f64) -> Self {
        let x0 = 0.5 * (nx.saturating_sub(1)) as f64 * pitch_mm;
        let y0 = 0.5 * (ny.saturating_sub(1)) as f64 * pitch_mm;
        let mut positions = Vec::with_capacity(nx * ny);
        for j in 0..ny {
            for i in 0..nx {
                let x = i as f64 * pitch_mm - x0;
                let y = j as f64 * pitch_mm - y0;
                let rr = x * x + y * y;
                let z = if dome_radius_mm.is_finite() && rr < dome_radius_mm * dome_radius_mm {
                    (dome_radius_mm * dome_radius_mm - rr).sqrt() - dome_radius_mm
                } else {
                    0.0
                };
                positions.push([x, y, z]);
            }
        }
        Self { positions }
    }

    /// The Tac3D layout measured from the PyTac3D example recordings
    /// (docs/hardware.md C.1): 20 x 20 markers, 1 mm pitch, dome radius 33 mm.
    pub fn tac3d() -> Self {
        Self::dome(20, 20, 1.0, crate::defaults::ELASTOMER_R_MM)
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

/// The sensor's imperfections.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseConfig {
    /// Gaussian noise per in-plane displacement component, mm.
    pub sigma_xy_mm: f64,
    /// Gaussian noise of dz, mm (4 um measured on Tac3D, docs/hardware.md C.1).
    pub sigma_z_mm: f64,
    /// Fraction of markers replaced by outliers in each contact frame
    /// (exactly round(fraction * markers) of them).
    pub outlier_fraction: f64,
    /// Outliers get an extra displacement in a uniformly random 3-D direction
    /// with a magnitude uniform in [min, max], mm.
    pub outlier_min_mm: f64,
    pub outlier_max_mm: f64,
    /// Probability that a frame is lost (the next delivered frame's index skips it).
    pub dropout_probability: f64,
}

impl NoiseConfig {
    /// No noise, no outliers, no lost frames.
    pub const NONE: Self = Self {
        sigma_xy_mm: 0.0,
        sigma_z_mm: 0.0,
        outlier_fraction: 0.0,
        outlier_min_mm: 0.05,
        outlier_max_mm: 0.5,
        dropout_probability: 0.0,
    };

    /// The same Gaussian noise on all three components, nothing else.
    pub fn gaussian(sigma_mm: f64) -> Self {
        Self { sigma_xy_mm: sigma_mm, sigma_z_mm: sigma_mm, ..Self::NONE }
    }

    pub fn with_outliers(mut self, fraction: f64) -> Self {
        self.outlier_fraction = fraction;
        self
    }

    pub fn with_dropouts(mut self, probability: f64) -> Self {
        self.dropout_probability = probability;
        self
    }
}

impl Default for NoiseConfig {
    /// 4 um on every component (the measured dz scatter; in-plane taken as
    /// large, which is conservative for the rotation estimate).
    fn default() -> Self {
        Self::gaussian(crate::defaults::MARKER_SIGMA_MM)
    }
}

/// One frame for a sensor in contact: the exact field of `state` plus noise
/// and outliers drawn from `rng`.
pub fn synth_frame(
    state: &ContactState,
    grid: &MarkerGrid,
    noise: &NoiseConfig,
    rng: &mut Rng,
    index: u64,
    t_s: f64,
) -> SensorFrame {
    synth_frame_on(state, None, grid, noise, rng, index, t_s)
}

/// [`synth_frame`] on a declared gel layer whose normal field departs from
/// Hertz's as `layer` says ([`ContactState::displacement_on`]).
pub fn synth_frame_on(
    state: &ContactState,
    layer: Option<&SurfaceShape>,
    grid: &MarkerGrid,
    noise: &NoiseConfig,
    rng: &mut Rng,
    index: u64,
    t_s: f64,
) -> SensorFrame {
    let mut displacements: Vec<[f64; 3]> = grid
        .positions
        .iter()
        .map(|p| {
            let mut d = state.displacement_on(p[0], p[1], layer);
            if noise.sigma_xy_mm > 0.0 {
                d[0] += noise.sigma_xy_mm * rng.normal();
                d[1] += noise.sigma_xy_mm * rng.normal();
            }
            if noise.sigma_z_mm > 0.0 {
                d[2] += noise.sigma_z_mm * rng.normal();
            }
            d
        })
        .collect();
    add_outliers(&mut displacements, noise, rng);
    SensorFrame { index, t_s, positions: grid.positions.clone(), displacements }
}

/// The frame a Tac3D sends without contact: displacements exactly zero (its
/// processing has a dead band; no noise reaches the client).
pub fn no_contact_frame(grid: &MarkerGrid, index: u64, t_s: f64) -> SensorFrame {
    SensorFrame { index, t_s, positions: grid.positions.clone(), displacements: vec![[0.0; 3]; grid.len()] }
}

/// Uniform on [lo, hi).
fn uniform_in(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.uniform()
}

/// Uniform integer in 0..n (n > 0), by Lemire's multiply-shift; the bias
/// (< n / 2^64) is irrelevant for picking markers.
fn below(rng: &mut Rng, n: usize) -> usize {
    ((rng.next_u64() as u128 * n as u128) >> 64) as usize
}

fn add_outliers(displacements: &mut [[f64; 3]], noise: &NoiseConfig, rng: &mut Rng) {
    let n = displacements.len();
    let count = ((noise.outlier_fraction.clamp(0.0, 1.0) * n as f64).round() as usize).min(n);
    if count == 0 {
        return;
    }
    // Partial Fisher–Yates: `count` distinct markers.
    let mut order: Vec<usize> = (0..n).collect();
    for k in 0..count {
        let j = k + below(rng, n - k);
        order.swap(k, j);
        let d = &mut displacements[order[k]];
        let magnitude = uniform_in(rng, noise.outlier_min_mm, noise.outlier_max_mm);
        // Uniform direction on the sphere: z uniform in [-1, 1], azimuth uniform.
        let z = uniform_in(rng, -1.0, 1.0);
        let phi = uniform_in(rng, 0.0, std::f64::consts::TAU);
        let s = (1.0 - z * z).sqrt();
        d[0] += magnitude * s * phi.cos();
        d[1] += magnitude * s * phi.sin();
        d[2] += magnitude * z;
    }
}

/// Where the contact is at rig time `t_s` (`None`: not touching).
pub type ContactFn = Box<dyn FnMut(f64) -> Option<ContactState> + Send>;

/// A sensor producing frames on demand from a contact history. The rig
/// coupling (stage position -> gamma1 and a, mount angle -> theta1) lives in
/// the `contact` closure.
pub struct SimulatedSensor {
    pub grid: MarkerGrid,
    pub noise: NoiseConfig,
    pub rng: Rng,
    pub contact: ContactFn,
    /// A declared gel layer's field shape (`None`: a half-space's, Hertz's).
    pub layer: Option<Arc<SurfaceShape>>,
    /// Index the next delivered frame gets unless frames are lost before it.
    next_index: u64,
    dropped: u64,
}

impl std::fmt::Debug for SimulatedSensor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimulatedSensor")
            .field("markers", &self.grid.len())
            .field("noise", &self.noise)
            .field("next_index", &self.next_index)
            .field("dropped", &self.dropped)
            .finish_non_exhaustive()
    }
}

impl SimulatedSensor {
    pub fn new(grid: MarkerGrid, noise: NoiseConfig, seed: u64, contact: ContactFn) -> Self {
        Self { grid, noise, rng: Rng::seed_from(seed), contact, layer: None, next_index: 0, dropped: 0 }
    }

    /// The sensor on a declared gel layer whose normal field departs from
    /// Hertz's as `layer` says.
    pub fn with_layer(mut self, layer: Option<Arc<SurfaceShape>>) -> Self {
        self.layer = layer;
        self
    }

    /// A real Tac3D's frame counter counts from its own start, not from 0.
    pub fn with_first_index(mut self, index: u64) -> Self {
        self.next_index = index;
        self
    }

    /// Frames lost so far (gaps in the delivered indices).
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// The next delivered frame, for rig time `t_s`. Lost frames (dropouts)
    /// only show as a gap in `index`, as on the real link.
    pub fn frame_at(&mut self, t_s: f64) -> SensorFrame {
        let state = (self.contact)(t_s);
        self.frame_for(state, t_s)
    }

    /// The next delivered frame for a contact given by the caller (`None`:
    /// not touching), bypassing the `contact` closure.
    pub fn frame_for(&mut self, state: Option<ContactState>, t_s: f64) -> SensorFrame {
        // Cap the run of lost frames so a probability of 1 cannot hang the caller.
        let mut lost = 0;
        while lost < 1000 && self.noise.dropout_probability > 0.0 && self.rng.uniform() < self.noise.dropout_probability
        {
            lost += 1;
        }
        self.dropped += lost;
        let index = self.next_index + lost;
        self.next_index = index + 1;
        match state {
            Some(state) => {
                synth_frame_on(&state, self.layer.as_deref(), &self.grid, &self.noise, &mut self.rng, index, t_s)
            }
            None => no_contact_frame(&self.grid, index, t_s),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn numeric_derivative(f: impl Fn(f64) -> f64, x: f64) -> f64 {
        let h = 1e-6;
        (f(x + h) - f(x - h)) / (2.0 * h)
    }

    #[test]
    fn normal_shape_is_hertz_and_continuous_at_the_edge() {
        assert_eq!(normal_shape(0.0), 1.0);
        assert!((normal_shape(1.0) - 0.5).abs() < 1e-15);
        assert!((normal_shape(1.0 + 1e-12) - 0.5).abs() < 1e-9);
        // Slope -1 from both sides at rho = 1 (C1 continuity of the Hertz field).
        assert!((numeric_derivative(normal_shape, 1.0 - 1e-4) + 1.0).abs() < 1e-3);
        assert!((numeric_derivative(normal_shape, 1.0 + 1e-4) + 1.0).abs() < 2e-2);
        // Far field of a point load: w -> 4 / (3 pi rho).
        let rho = 200.0;
        assert!((normal_shape(rho) * rho - 4.0 / (3.0 * PI)).abs() < 1e-4);
        // Monotone decrease.
        let mut prev = 1.0;
        for k in 1..400 {
            let v = normal_shape(k as f64 * 0.02);
            assert!(v < prev);
            prev = v;
        }
    }

    #[test]
    fn an_adhesive_contact_is_hertz_plus_a_flat_punch() {
        // The punch: flat inside, continuous at the edge, (2/pi)/rho far out.
        assert_eq!(punch_shape(0.3), 1.0);
        assert!((punch_shape(1.0 + 1e-12) - 1.0).abs() < 1e-5);
        assert!((punch_shape(100.0) * 100.0 - 2.0 / PI).abs() < 1e-4);
        assert!((punch_radial_shape(1.0) - 1.0).abs() < 1e-15 && (punch_radial_shape(1.0 + 1e-12) - 1.0).abs() < 1e-9);
        assert!((punch_radial_coefficient(0.0) - 1.0 / PI).abs() < 1e-15 && punch_radial_coefficient(0.5) == 0.0);
        // JKR (Johnson 1985, 5.3): inside the contact the surface is the
        // indenter's shape, gamma1 - c r^2 / 2 with c the Hertz part's
        // gamma1_H / a^2, whatever the punch; it reaches the edge at
        // gamma1_H / 2 + p, and outside it falls off faster than Hertz's.
        let (a, hertz, p) = (1.5, 0.39, -0.12);
        let jkr = ContactState::new([0.0, 0.0], hertz + p, a, 0.0).with_punch(p);
        let plain = ContactState::new([0.0, 0.0], hertz + p, a, 0.0);
        let c = hertz / (a * a);
        for r in [0.0, 0.4, 1.0, 1.49] {
            assert!((-jkr.displacement_at(r, 0.0)[2] - (hertz + p - 0.5 * c * r * r)).abs() < 1e-12, "r {r}");
        }
        assert!((-jkr.displacement_at(a, 0.0)[2] - (0.5 * hertz + p)).abs() < 1e-12);
        for r in [1.6, 2.0, 3.0, 6.0] {
            let (w, w_plain) = (-jkr.displacement_at(r, 0.0)[2], -plain.displacement_at(r, 0.0)[2]);
            let want = hertz * normal_shape(r / a) + p * 2.0 / PI * (a / r).asin();
            assert!((w - want).abs() < 1e-12 && w < w_plain, "r {r}: {w} vs {want}, plain {w_plain}");
        }
        // A pulling punch moves the surface outward in-plane (nu < 0.5).
        let jkr = jkr.with_nu1(0.39);
        let d = jkr.displacement_at(3.0, 0.0);
        let hertz_only = -hertz * radial_coefficient(0.39) * radial_shape(2.0);
        assert!((d[0] - (hertz_only - p * punch_radial_coefficient(0.39) * 0.5)).abs() < 1e-12 && d[0] > hertz_only);
    }

    #[test]
    fn twist_shape_matches_disc_field_and_decays_as_inverse_square() {
        assert_eq!(twist_shape(0.5), 0.5);
        assert!((twist_shape(1.0 + 1e-12) - 1.0).abs() < 1e-5);
        // docs/physics.md 2.7: u = (2 phi / pi) (r asin(s/r) - s sqrt(1 - s^2/r^2)), s = a = 1.
        let r: f64 = 2.5;
        let disc = 2.0 / PI * (r * (1.0 / r).asin() - (1.0 - 1.0 / (r * r)).sqrt());
        assert!((twist_shape(r) - disc).abs() < 1e-15);
        // Far field of a twisted disc: u -> 4 a / (3 pi rho^2) * theta a / a.
        let rho = 100.0;
        assert!((twist_shape(rho) * rho * rho - 4.0 / (3.0 * PI)).abs() < 1e-4);
    }

    #[test]
    fn radial_field_is_continuous_and_vanishes_when_incompressible() {
        assert_eq!(radial_coefficient(0.5), 0.0);
        assert!((radial_coefficient(0.0) - 2.0 / (3.0 * PI)).abs() < 1e-15);
        assert!((radial_shape(1.0) - 1.0).abs() < 1e-15);
        assert!((radial_shape(1.0 + 1e-12) - 1.0).abs() < 1e-9);
        // Near the centre the contraction is linear in r: 1.5 rho.
        assert!((radial_shape(1e-4) / 1e-4 - 1.5).abs() < 1e-6);
    }

    #[test]
    fn field_at_centre_and_twist_direction() {
        let s = ContactState::new([0.3, -0.2], 1.2, 2.0, 0.01).with_nu1(0.4);
        let d = s.displacement_at(0.3, -0.2);
        assert_eq!(d, [0.0, 0.0, -1.2]);
        // A point on +x of the centre, inside the contact: positive twist moves it +y.
        let d = s.displacement_at(1.3, -0.2);
        // Contracted by u_r (r = 1, rho = 0.5), then turned by theta.
        let u_r = -1.2 * radial_coefficient(0.4) * radial_shape(0.5);
        assert!((d[1] - 0.01f64.sin() * (1.0 + u_r)).abs() < 1e-15);
        // Radial contraction: moves toward the centre (-x).
        assert!(d[0] < 0.0);
        assert!((d[2] + 1.2 * 0.875).abs() < 1e-14);
    }

    #[test]
    fn dome_grid_is_tac3d_like() {
        let g = MarkerGrid::tac3d();
        assert_eq!(g.len(), 400);
        let (min_x, max_x) = g.positions.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| (lo.min(p[0]), hi.max(p[0])));
        assert!((max_x - min_x - 19.0).abs() < 1e-12);
        // Every point lies on the 33 mm sphere centred at (0, 0, -33).
        for p in &g.positions {
            let r = (p[0] * p[0] + p[1] * p[1] + (p[2] + 33.0).powi(2)).sqrt();
            assert!((r - 33.0).abs() < 1e-9);
        }
    }

    #[test]
    fn noise_has_the_requested_scatter_and_no_contact_is_exact_zero() {
        let grid = MarkerGrid::tac3d();
        let state = ContactState::new([0.0, 0.0], 1.0, 2.0, 0.0);
        let mut rng = Rng::seed_from(3);
        let noise = NoiseConfig::gaussian(0.004);
        let mut sum2 = 0.0;
        let mut n = 0.0;
        for k in 0..20 {
            let f = synth_frame(&state, &grid, &noise, &mut rng, k, k as f64 / 30.0);
            for (p, d) in f.positions.iter().zip(&f.displacements) {
                let exact = state.displacement_at(p[0], p[1]);
                sum2 += (d[2] - exact[2]).powi(2) + (d[0] - exact[0]).powi(2);
                n += 2.0;
            }
        }
        let sigma = (sum2 / n).sqrt();
        assert!((sigma - 0.004).abs() < 0.0002, "sigma {sigma}");
        let f = no_contact_frame(&grid, 5, 0.1);
        assert!(f.displacements.iter().all(|d| *d == [0.0; 3]));
    }

    #[test]
    fn outliers_hit_exactly_the_requested_number_of_markers() {
        let grid = MarkerGrid::tac3d();
        let state = ContactState::new([0.0, 0.0], 1.0, 2.0, 0.0);
        let mut rng = Rng::seed_from(11);
        let noise = NoiseConfig::NONE.with_outliers(0.05);
        let f = synth_frame(&state, &grid, &noise, &mut rng, 0, 0.0);
        let moved = f
            .positions
            .iter()
            .zip(&f.displacements)
            .filter(|(p, d)| {
                let e = state.displacement_at(p[0], p[1]);
                let dd = ((d[0] - e[0]).powi(2) + (d[1] - e[1]).powi(2) + (d[2] - e[2]).powi(2)).sqrt();
                assert!(dd < 0.5 + 1e-12);
                dd > 0.05 - 1e-12
            })
            .count();
        assert_eq!(moved, 20);
    }

    #[test]
    fn simulated_sensor_follows_its_contact_and_numbers_lost_frames() {
        let contact: ContactFn =
            Box::new(|t| (t >= 1.0).then(|| ContactState::new([0.0, 0.0], 0.5 * (t - 1.0), 1.0, 0.0)));
        let mut sensor = SimulatedSensor::new(MarkerGrid::tac3d(), NoiseConfig::NONE.with_dropouts(0.3), 9, contact)
            .with_first_index(1000);
        let mut last = None;
        let mut gaps = 0;
        for k in 0..200 {
            let t = k as f64 / 30.0;
            let f = sensor.frame_at(t);
            if let Some(prev) = last {
                assert!(f.index > prev);
                gaps += f.index - prev - 1;
            } else {
                assert!(f.index >= 1000);
            }
            last = Some(f.index);
            let peak = f.displacements.iter().map(|d| -d[2]).fold(0.0, f64::max);
            if t < 1.0 {
                assert!(f.displacements.iter().all(|d| *d == [0.0; 3]));
            } else {
                // No marker sits on the centre: the largest reading is below gamma1.
                assert!(peak <= 0.5 * (t - 1.0) + 1e-12);
            }
        }
        // About 30 % lost: 200 delivered frames hide ~86 lost ones.
        assert!(gaps >= 40 && sensor.dropped() >= gaps, "gaps {gaps}");
        assert!(sensor.dropped() < 200);
    }
}
