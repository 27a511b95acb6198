//! Frame processing: from one marker frame of a Tac3D-class sensor to the two
//! numbers the EasyCalib method uses — gamma1, the peak normal displacement
//! of the elastomer, and theta1, the rotation of the contact region — plus the
//! contact centre and radius.
//!
//! * **gamma1**: a quadratic surface is fitted to the normal displacement of
//!   the markers around the deepest point and its maximum taken, so the peak
//!   between markers is found (sub-marker interpolation). Inside a Hertz
//!   contact the normal field is exactly a paraboloid, gamma1 (1 - r^2/(2a^2)),
//!   so the fit window is shrunk to lie inside the contact once its radius is
//!   known, and the fit is then exact for a noise-free Hertz field.
//! * **contact radius**: from the same paraboloid, a = sqrt(gamma1 / -k) with
//!   k the mean curvature (w_xx + w_yy)/2 = -gamma1/a^2.
//! * **theta1**: the rigid in-plane rotation about the contact centre that
//!   best maps the markers of the stick region (r <= `stick_fraction` a), a
//!   2-D orthogonal Procrustes fit by SVD, with its residual.
//! * Outlier markers are rejected in both fits by a median-based scale and the
//!   fits repeated.

mod estimator;
pub mod fit;
mod layer;

use devices::sensor::SensorFrame;
use serde::Serialize;

pub use estimator::{CurvatureLearner, FrameEstimator};
use fit::{Curvature, fit_hertz, fit_quadratic, fit_rotation, paraboloid_errors};
pub use layer::{LayerSurface, TieDrift};

use crate::numerics::stats::{MAD_TO_SIGMA, median};

/// Contacts at least this many marker pitches wide, fitted at a known centre,
/// also measure their curvature with the radius free (docs/sensing.md).
const MID_CONTACT_PITCHES: f64 = 1.15;

/// A small contact is read as adhesive (Hertz plus a flat punch) only when
/// the punch lowers the markers' chi-square by more than this (one more
/// parameter, held to one side: a clean contact's frames pass it about three
/// times in a hundred thousand, and only those whose tied fit is already poor
/// are tried).
const PUNCH_CHI2: f64 = 16.0;

/// Resolved contacts up to this many pitches wide are probed for a punch
/// (beyond, the edge lies among markers far from the centre the probe
/// does not weigh).
const PROBE_PITCHES: f64 = 2.5;

/// The markers within `reach` of `centre` as (x, y, depth), each depth with
/// the spheres' sag of a contact of radius `sag_radius` taken out
/// ([`hertz_depth`]).
fn markers_within(
    frame: &SensorFrame,
    centre: [f64; 2],
    reach: f64,
    sag_radius: f64,
    cfg: &SensingConfig,
) -> Vec<[f64; 3]> {
    frame
        .positions
        .iter()
        .zip(&frame.displacements)
        .filter(|(p, _)| dist2(xy(p), centre) <= reach * reach)
        .map(|(p, d)| [p[0], p[1], hertz_depth(-d[2], dist2(xy(p), centre).sqrt(), sag_radius, cfg)])
        .collect()
}

/// Whether a resolved contact of depth `gamma1` (read by its paraboloid,
/// right whatever the punch) at `centre` shows a punch beyond chance: the
/// tied punch field fits the markers within three radii better than Hertz's
/// field of that depth with a = sqrt(gamma1 / c) by more than [`PUNCH_CHI2`].
fn adhesion_probe(
    frame: &SensorFrame,
    centre: [f64; 2],
    c: f64,
    gamma1: f64,
    radius: f64,
    cfg: &SensingConfig,
) -> bool {
    let pts = markers_within(frame, centre, 3.0 * radius, (gamma1 / c).sqrt(), cfg);
    let Some((p, kept)) = punch_stage(&pts, centre, c, gamma1, cfg) else {
        return false;
    };
    // The marker noise the run has pooled, or else this fit's own (the
    // test is then an F-test with the punch fit's degrees of freedom).
    let m = kept.iter().filter(|&&k| k).count();
    let own = (m > 2).then(|| (p.sse / (m - 2) as f64).sqrt());
    let Some(noise) = cfg.marker_noise_mm.map(|n| n.0).or(own).filter(|n| *n > 0.0) else {
        return false;
    };
    // Against the tied Hertz field at its own best depth (the punch adds
    // one parameter to it): the paraboloid's depth is right for a resolved
    // contact but not for the approach's smaller ones, and a Hertz field
    // held at a misread depth would take the misreading for a punch.
    let on: Vec<(f64, f64)> = pts
        .iter()
        .zip(&kept)
        .filter(|(_, k)| **k)
        .map(|(q, _)| ((q[0] - centre[0]).hypot(q[1] - centre[1]), q[2]))
        .collect();
    let layer = cfg.layer_shape();
    let hertz =
        |g: f64| on.iter().map(|&(r, z)| (z - g * fit::field_shape(layer, r, (g / c).sqrt())).powi(2)).sum::<f64>();
    let hertz = crate::numerics::golden_min(hertz, 0.3 * gamma1, 2.0 * gamma1, 1e-4 * gamma1).1.min(hertz(gamma1));
    p.punch < 0.0 && (hertz - p.sse) / (noise * noise) > PUNCH_CHI2
}

/// Whether a frame whose contact its paraboloid resolves shows a flat punch
/// beyond chance, at the curvature and centre `cfg` knows ([`adhesion_probe`]);
/// `None` when the frame cannot tell (no contact, no paraboloid, a contact
/// too wide for the probe, or `cfg` without curvature or centre). Without
/// the run's marker noise the probe weighs the punch against its own fit's.
pub(crate) fn shows_punch(frame: &SensorFrame, cfg: &SensingConfig) -> Option<bool> {
    validate(frame).ok()?;
    let (c, at) = (cfg.contact_curvature_per_mm?.0, cfg.contact_centre_mm?);
    let (seed, seed_depth, pitch) = deepest_marker(frame);
    if !(c > 0.0 && seed_depth >= cfg.min_depth_mm) {
        return None;
    }
    let pitch = if pitch.is_finite() && pitch > 0.0 { pitch } else { 1.0 };
    let d = quadratic_stage(frame, seed, pitch, cfg).ok()?;
    (d.radius < PROBE_PITCHES * pitch && d.gamma1 >= cfg.min_depth_mm)
        .then(|| adhesion_probe(frame, at, c, d.gamma1, d.radius.max(pitch), cfg))
}

/// The range a run's layer weight is learnt over (docs/sensing.md, "On a
/// layer"): a little beyond the family's two gels each way.
const LAYER_WEIGHT_RANGE: (f64, f64) = (-0.75, 1.25);

/// Where between its family's two gels ([`layer::ShapeFamily`]) a resolved
/// contact's field lies: the weight whose field, with its own depth and
/// radius at the held `centre`, fits the markers within three radii best
/// (the outliers those of the middle gel's fit). `None` when the fit fails.
pub(crate) fn layer_weight(
    frame: &SensorFrame,
    centre: [f64; 2],
    gamma1: f64,
    radius: f64,
    family: &layer::ShapeFamily,
    cfg: &SensingConfig,
) -> Option<f64> {
    let pts = markers_within(frame, centre, 3.0 * radius, radius, cfg);
    let (_, middle) = family.at(0.5)?;
    let (k, floor) = (cfg.outlier_sigmas, cfg.outlier_floor_mm);
    let first = fit_hertz(&pts, Some(&middle), (gamma1, centre, radius), k, floor, Curvature::Free, true)?;
    let start = [first.gamma1, centre[0], centre[1], first.radius];
    let sse = |s: f64| {
        family.at(s).and_then(|(_, shape)| fit::field_sse(&pts, &shape, &first.kept, start)).unwrap_or(f64::INFINITY)
    };
    let (lo, hi) = LAYER_WEIGHT_RANGE;
    let (s, best) = crate::numerics::golden_min(sse, lo, hi, 1e-3);
    best.is_finite().then_some(s)
}

/// Settings of the frame processing.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SensingConfig {
    /// A frame is "no contact" unless the elastomer is pressed at least this
    /// deep around its deepest marker, mm.
    pub min_depth_mm: f64,
    /// Radius of the first quadratic-fit window, in marker pitches (1.5
    /// takes the 3 x 3 markers around the deepest one).
    pub initial_window_pitches: f64,
    /// Once the contact radius is known the window is this fraction of it
    /// (kept inside the contact, where the Hertz field is a paraboloid), but
    /// never smaller than the initial window.
    pub window_fraction: f64,
    /// Stick region for theta1, as a fraction of the contact radius. Under
    /// full stick the whole contact turns rigidly; the edge is left out
    /// because the field just outside it changes fast (as sqrt(r - a)).
    pub stick_fraction: f64,
    /// Fewest markers used for theta1; the nearest ones to the centre are
    /// taken when the stick region holds fewer (a tiny contact).
    pub min_stick_markers: usize,
    /// Fit the axisymmetric paraboloid c0 + c1 x + c2 y + c3 r^2 (Hertz's
    /// shape) instead of the general six-term quadratic surface.
    pub isotropic: bool,
    /// Fit Hertz's normal field (inside and outside the contact) when the
    /// contact is too small for a quadratic window inside it.
    pub hertz_refine: bool,
    /// Markers farther than this many robust sigmas from a fit are outliers.
    pub outlier_sigmas: f64,
    /// Residuals below this are never outliers (keeps noise-free frames from
    /// rejecting markers over rounding), mm.
    pub outlier_floor_mm: f64,
    /// The largest curvature the normal field can have inside the contact,
    /// 1/R2 + 1/R1 (1/mm; R1 infinite for a flat gel), from the indenter the
    /// rig declares. It settles contacts smaller than the marker pitch, whose
    /// depth the markers around them cannot separate from their radius
    /// (docs/sensing.md, "Small contacts"). `None`: not known, not used.
    pub max_curvature_per_mm: Option<f64>,
    /// The normal field's curvature inside the contact, gamma1 / a^2 (1/mm),
    /// and its standard error, as measured on this run's resolved contacts
    /// ([`FrameEstimator`] learns it). Contacts too small for the paraboloid
    /// are then fitted with the radius tied to the depth, a = sqrt(gamma1 / c)
    /// (docs/sensing.md, "Small contacts"). `None`: not known yet.
    pub contact_curvature_per_mm: Option<(f64, f64)>,
    /// Where the indenter touches the sensor, in marker coordinates (mm), as
    /// learnt on resolved contacts: it stays put through a normal sweep. With
    /// the curvature known too, a contact too small to resolve is fitted
    /// there with gamma1 its only unknown: no search for the deepest spot,
    /// which in a frame of pure noise finds a few µm of "contact" anywhere.
    pub contact_centre_mm: Option<[f64; 2]>,
    /// The marker noise pooled over many frames, mm: normal (dz) and
    /// in-plane (tangential). A frame's own residuals hold a handful of
    /// degrees of freedom when its contact is small, so its errors come from
    /// these instead, unless its residuals are clearly larger (a field the
    /// model does not follow). [`FrameEstimator`] learns them.
    pub marker_noise_mm: Option<(f64, f64)>,
    /// The gel is known to be tacky (this run's frames showed adhesive
    /// contacts, [`FrameEstimator`] counts them): a small contact at the
    /// known centre is then always fitted with the punch term, not only when
    /// one frame's markers ask for it (docs/sensing.md, "Adhesive contacts").
    pub adhesive: bool,
    /// Probe resolved contacts at the known centre for a punch
    /// ([`FrameEstimator`] asks while it has not decided `adhesive`).
    pub probe_adhesion: bool,
    /// The indenter's and the elastomer's radii (mm; infinite: flat or not
    /// known). Inside a contact the gel's surface follows the two spheres,
    /// whose sag departs from a paraboloid by r^4 / 8R^3 and more (17 µm at
    /// 2 mm and 0.1 mm at 3 mm from the axis of a 5 mm indenter); the
    /// paraboloid fit takes that part out first (docs/sensing.md, "The
    /// spheres inside a wide contact").
    pub indenter_radius_mm: f64,
    pub elastomer_radius_mm: f64,
    /// On a declared gel layer, what the sensor sees of it
    /// ([`LayerSurface`]): how gamma1 / a² changes with the contact's radius
    /// (the curvature learnt on resolved contacts is carried by it to the
    /// size of the small ones it ties) and how the normal field departs from
    /// Hertz's (the field fits take the layer's shape). `None`: a
    /// half-space, where neither applies. Not serialised (a table).
    #[serde(skip)]
    pub layer: Option<LayerSurface>,
}

/// A frame whose own noise estimate exceeds the pooled one by more than this
/// factor keeps its own (about 2 % of frames with 8 degrees of freedom do by
/// chance).
const OWN_NOISE_FACTOR: f64 = 1.5;

/// The noise a frame's errors are computed with: the pooled one unless the
/// frame's own is clearly larger.
fn noise_for_errors(own: f64, pooled: Option<f64>) -> f64 {
    match pooled {
        // A frame without a usable noise of its own (NaN) takes the pooled one too.
        Some(p) if p > 0.0 && (own.is_nan() || own <= OWN_NOISE_FACTOR * p) => p,
        _ => own,
    }
}

impl SensingConfig {
    /// The declared layer's field shape, if any.
    pub fn layer_shape(&self) -> Option<&sim::sensor::shape::SurfaceShape> {
        self.layer.as_ref().map(|l| &*l.shape)
    }

    /// The defaults, for an indenter of radius `indenter_r_mm` on an elastomer
    /// of radius `elastomer_r_mm` (infinite when flat).
    pub fn for_contact(indenter_r_mm: f64, elastomer_r_mm: f64) -> Self {
        let c = 1.0 / indenter_r_mm + if elastomer_r_mm.is_finite() { 1.0 / elastomer_r_mm } else { 0.0 };
        Self {
            max_curvature_per_mm: (c.is_finite() && c > 0.0).then_some(c),
            indenter_radius_mm: indenter_r_mm,
            elastomer_radius_mm: elastomer_r_mm,
            ..Self::default()
        }
    }
}

impl Default for SensingConfig {
    fn default() -> Self {
        Self {
            min_depth_mm: 0.002,
            initial_window_pitches: 1.5,
            window_fraction: 0.8,
            stick_fraction: 0.95,
            min_stick_markers: 5,
            isotropic: true,
            hertz_refine: true,
            outlier_sigmas: 4.0,
            outlier_floor_mm: 2e-4,
            max_curvature_per_mm: None,
            contact_curvature_per_mm: None,
            contact_centre_mm: None,
            marker_noise_mm: None,
            adhesive: false,
            probe_adhesion: false,
            indenter_radius_mm: f64::INFINITY,
            elastomer_radius_mm: f64::INFINITY,
            layer: None,
        }
    }
}

/// What one frame says about the contact.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Measurement {
    /// The frame's counter.
    pub index: u64,
    /// The frame's sensor-side time, s.
    pub t_s: f64,
    /// Peak normal displacement of the elastomer (into it, > 0), mm.
    pub gamma1_mm: f64,
    /// Rotation of the contact region about the outward normal
    /// (counter-clockwise seen from outside the elastomer), degrees.
    pub theta1_deg: f64,
    /// Where the peak is, in the frame's marker coordinates, mm.
    pub contact_centre_mm: [f64; 2],
    /// Contact radius from the curvature of the normal field, mm.
    pub contact_radius_mm: f64,
    /// Standard error of gamma1 from the field fit behind it (the marker
    /// noise seen in its residuals, through the fit; with a tied radius, the
    /// tie's own error too), mm.
    pub gamma1_sd_mm: f64,
    /// The part of `gamma1_sd_mm` that a known curvature's error makes, mm
    /// (0 without one): shared by every frame fitted with that curvature, so
    /// it stays whole in a mean of frames.
    pub gamma1_common_sd_mm: f64,
    /// This frame's own marker noise: the depth fit's residual rms corrected
    /// for its free parameters (mm) with its degrees of freedom, and the same
    /// for the rotation fit's tangential residuals. [`FrameEstimator`] pools
    /// them into [`SensingConfig::marker_noise_mm`].
    pub depth_noise_mm: f64,
    pub depth_dof: usize,
    pub rotation_noise_mm: f64,
    pub rotation_dof: usize,
    /// The field's curvature inside the contact, gamma1 / a^2 (1/mm), with its
    /// standard error, when this frame measured it: the paraboloid lay inside
    /// the contact, or a contact over 1.15 pitches was fitted at a known
    /// centre with its radius free. What [`FrameEstimator`] learns from.
    pub contact_curvature_per_mm: Option<(f64, f64)>,
    /// The flat-punch part of gamma1 (mm, < 0) when the frame was read as an
    /// adhesive contact, else `None`.
    pub punch_mm: Option<f64>,
    /// The frame's markers showed a flat punch beyond chance: read with it,
    /// or (a resolved contact, read by its paraboloid) probed for one.
    pub adhesive: bool,
    /// RMS residual of the quadratic fit, mm.
    pub gamma1_residual_mm: f64,
    /// RMS tangential residual of the stick markers after the rotation, mm.
    pub theta1_residual_mm: f64,
    /// Standard error of theta1 implied by that residual, degrees.
    pub theta1_std_deg: f64,
    /// Markers in the final quadratic fit.
    pub depth_markers: usize,
    /// Markers in the final rotation fit.
    pub stick_markers: usize,
    /// Distinct markers used by either final fit.
    pub markers_used: usize,
    /// Distinct markers rejected as outliers by either fit.
    pub outliers: usize,
}

/// Why a frame gave no measurement.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SensingError {
    #[error("frame {index}: no markers")]
    Empty { index: u64 },
    #[error("frame {index}: {positions} marker positions but {displacements} displacements")]
    LengthMismatch { index: u64, positions: usize, displacements: usize },
    #[error("frame {index}: marker {marker} has a non-finite {what}")]
    NotFinite { index: u64, marker: usize, what: &'static str },
    #[error("frame {index}: no contact (deepest point {depth_mm:.4} mm)")]
    NoContact { index: u64, depth_mm: f64 },
    #[error("frame {index}: {stage} needs {needed} markers, found {found}")]
    TooFewMarkers { index: u64, stage: &'static str, found: usize, needed: usize },
    #[error("frame {index}: the normal field has no maximum near marker {marker} (not a press)")]
    NoPeak { index: u64, marker: usize },
}

/// Reject frames that cannot be processed, naming the marker.
fn validate(frame: &SensorFrame) -> Result<(), SensingError> {
    let index = frame.index;
    if frame.positions.len() != frame.displacements.len() {
        return Err(SensingError::LengthMismatch {
            index,
            positions: frame.positions.len(),
            displacements: frame.displacements.len(),
        });
    }
    if frame.positions.is_empty() {
        return Err(SensingError::Empty { index });
    }
    for (marker, (p, d)) in frame.positions.iter().zip(&frame.displacements).enumerate() {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(SensingError::NotFinite { index, marker, what: "position" });
        }
        if !d.iter().all(|v| v.is_finite()) {
            return Err(SensingError::NotFinite { index, marker, what: "displacement" });
        }
    }
    Ok(())
}

/// The marker's depth as Hertz's field would have it: its measured depth
/// plus the spheres' sag at `r_mm` from the centre of a contact of radius
/// `contact_radius_mm` (docs/sensing.md, "The spheres inside a wide contact").
fn hertz_depth(depth_mm: f64, r_mm: f64, contact_radius_mm: f64, cfg: &SensingConfig) -> f64 {
    depth_mm
        + sim::sensor::field::spheres_sag_mm(r_mm, contact_radius_mm, cfg.indenter_radius_mm, cfg.elastomer_radius_mm)
}

fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)
}

fn xy(p: &[f64; 3]) -> [f64; 2] {
    [p[0], p[1]]
}

/// The deepest point that is not a lone outlier: among the deepest markers,
/// the one whose median depth with its 4 nearest neighbours is largest (a
/// lone spike has no deep neighbours; a peak between markers has two). Returns
/// (marker, neighbourhood median depth, local marker pitch).
fn deepest_marker(frame: &SensorFrame) -> (usize, f64, f64) {
    let n = frame.positions.len();
    let depth = |i: usize| -frame.displacements[i][2];
    let mut order: Vec<usize> = (0..n).collect();
    let k = (n / 16).clamp(16, n.max(1)).min(n);
    if k < n {
        order.select_nth_unstable_by(k - 1, |&a, &b| depth(b).total_cmp(&depth(a)));
    }
    order[..k].sort_unstable_by(|&a, &b| depth(b).total_cmp(&depth(a)));
    let mut best = (order[0], f64::NEG_INFINITY, 0.0);
    let mut near: Vec<(f64, usize)> = Vec::with_capacity(n);
    let mut around = Vec::with_capacity(5);
    for &c in &order[..k] {
        // Deepest first: a shallower marker can only score higher with two
        // neighbours deeper than the best score, and those came earlier.
        if depth(c) < best.1 {
            break;
        }
        let pc = xy(&frame.positions[c]);
        near.clear();
        near.extend((0..n).filter(|&j| j != c).map(|j| (dist2(pc, xy(&frame.positions[j])), j)));
        let m = near.len().min(4);
        if m > 0 && m < near.len() {
            near.select_nth_unstable_by(m - 1, |a, b| a.0.total_cmp(&b.0));
        }
        let pitch = near[..m].iter().map(|e| e.0).filter(|&d| d > 0.0).fold(f64::INFINITY, f64::min).sqrt();
        around.clear();
        around.push(depth(c));
        around.extend(near[..m].iter().map(|&(_, j)| depth(j)));
        let score = median(&mut around);
        if score > best.1 {
            best = (c, score, pitch);
        }
    }
    best
}

/// The normal field's peak as one of the fits found it.
#[derive(Debug, Clone)]
struct Depth {
    gamma1: f64,
    centre: [f64; 2],
    radius: f64,
    /// Markers the fit looked at, and which of them it kept.
    selected: Vec<usize>,
    kept: Vec<bool>,
    rms: f64,
    /// Radius of the final quadratic window (0 for the Hertz fit).
    window: f64,
    /// Standard error of gamma1, mm.
    gamma1_sd: f64,
    /// The part of `gamma1_sd` common to frames fitted with the same known curvature.
    gamma1_common_sd: f64,
    /// The marker noise `gamma1_sd` was computed with (residual rms corrected
    /// for the free parameters), mm, and its degrees of freedom.
    noise_sd: f64,
    dof: usize,
    /// The paraboloid's curvature -2 c3 = gamma1 / a^2 and its standard error.
    curvature: Option<(f64, f64)>,
    /// The punch part of gamma1 when read as an adhesive contact.
    punch: Option<f64>,
    /// The markers showed a punch beyond chance (read with it, or probed).
    adhesive: bool,
}

/// What a paraboloid of peak `peak` and curvature `curvature` (1/mm), fitted
/// within `window` of the centre, says of a contact on a layer of field
/// `layer`: gamma1, the contact radius and the paraboloid's curvature over
/// gamma1 / a² there, found together (the last two depend on the radius) from
/// Hertz's reading `hertz_radius`. `None` when they do not settle.
fn through_layer(
    layer: &sim::sensor::shape::SurfaceShape,
    peak: f64,
    curvature: f64,
    hertz_radius: f64,
    markers: &MarkersFitted,
) -> Option<(f64, f64, f64)> {
    if !(peak > 0.0 && curvature > 0.0 && hertz_radius > 0.0) {
        return None;
    }
    let mut a = hertz_radius;
    for _ in 0..20 {
        let (p, ratio) = markers.paraboloid_of(layer, a)?;
        let g = peak / p;
        let next = (g * ratio / curvature).sqrt();
        if !(next.is_finite() && next > 0.0 && p > 0.0 && ratio > 0.0) {
            return None;
        }
        if (next - a).abs() <= 1e-9 * a {
            return Some((g, next, ratio));
        }
        a = next;
    }
    None
}

/// The markers a quadratic window fitted, about the contact's centre: what
/// a paraboloid fitted to the layer's field over those same markers reads
/// (docs/sensing.md, "On a layer").
struct MarkersFitted {
    /// (x, y) of each kept marker, relative to the centre the fit found.
    at: Vec<[f64; 2]>,
    isotropic: bool,
}

impl MarkersFitted {
    fn of(pts: &[[f64; 3]], kept: &[bool], peak: [f64; 2], isotropic: bool) -> Self {
        let at = pts.iter().zip(kept).filter(|(_, k)| **k).map(|(q, _)| [q[0] - peak[0], q[1] - peak[1]]).collect();
        Self { at, isotropic }
    }

    /// Per unit gamma1, the peak and the curvature times a² of the quadratic
    /// the window's own fit gives on the field of a contact of radius `a_mm`
    /// (Hertz's plus the layer's departure) at these markers, equally
    /// weighted: 1 and 1 for Hertz. `None` when the markers carry no peak.
    fn paraboloid_of(&self, layer: &sim::sensor::shape::SurfaceShape, a_mm: f64) -> Option<(f64, f64)> {
        if !(a_mm > 0.0 && a_mm.is_finite()) {
            return None;
        }
        let pts: Vec<[f64; 3]> = self
            .at
            .iter()
            .map(|p| {
                let r = p[0].hypot(p[1]);
                [p[0], p[1], sim::sensor::field::normal_shape(r / a_mm) + layer.departure(r, a_mm)]
            })
            .collect();
        let q = fit_quadratic(&pts, self.isotropic, f64::INFINITY, f64::INFINITY)?;
        let (_, p) = q.surface.maximum()?;
        Some((p, -q.surface.mean_curvature() * a_mm * a_mm))
    }
}

/// Quadratic fit, re-centred on its own peak with a window shrunk or grown
/// to lie inside the contact, until the window's markers stop changing.
fn quadratic_stage(frame: &SensorFrame, seed: usize, pitch: f64, cfg: &SensingConfig) -> Result<Depth, SensingError> {
    let index = frame.index;
    let n = frame.positions.len();
    let min_window = cfg.initial_window_pitches * pitch;
    let mut centre = xy(&frame.positions[seed]);
    let mut window = min_window;
    let mut best: Option<Depth> = None;
    // The window lies inside the contact (it is kept to a fraction of the
    // radius; a wider one hands over to the Hertz field's fit): there the
    // surface follows the spheres.
    let reach = f64::INFINITY;
    for _ in 0..5 {
        let mut sel: Vec<usize> = Vec::new();
        let mut w = window;
        // Grow the window until it can carry a quadratic with spare points.
        while sel.len() < 9 && w < 10.0 * min_window.max(pitch) {
            sel = (0..n).filter(|&i| dist2(xy(&frame.positions[i]), centre) <= w * w).collect();
            w += 0.25 * pitch;
        }
        if best.as_ref().is_some_and(|b| b.selected == sel) {
            break;
        }
        let pts: Vec<[f64; 3]> = sel
            .iter()
            .map(|&i| {
                let p = frame.positions[i];
                let (x, y) = (p[0] - centre[0], p[1] - centre[1]);
                [x, y, hertz_depth(-frame.displacements[i][2], x.hypot(y), reach, cfg)]
            })
            .collect();
        let found = pts.len();
        let qf = fit_quadratic(&pts, cfg.isotropic, cfg.outlier_sigmas, cfg.outlier_floor_mm)
            .ok_or(SensingError::TooFewMarkers { index, stage: "quadratic fit", found, needed: 7 })?;
        let (peak, gamma1) = qf.surface.maximum().ok_or(SensingError::NoPeak { index, marker: seed })?;
        // A maximum outside the window is an extrapolation, not a peak.
        if peak[0].hypot(peak[1]) > w {
            return Err(SensingError::NoPeak { index, marker: seed });
        }
        let radius = (gamma1 / -qf.surface.mean_curvature()).sqrt();
        centre = [centre[0] + peak[0], centre[1] + peak[1]];
        // How far from the peak the fit reached: beyond the contact radius
        // the field is no longer a paraboloid.
        let used_window = sel.iter().map(|&i| dist2(xy(&frame.positions[i]), centre)).fold(0.0, f64::max).sqrt();
        window = (cfg.window_fraction * radius).max(min_window);
        let errors = if cfg.isotropic { paraboloid_errors(&pts, &qf.kept, peak, qf.rms) } else { None };
        // paraboloid_errors' noise: the rms over the kept markers, less its 4 parameters.
        let m_kept = qf.kept.iter().filter(|&&b| b).count();
        let qf_dof = m_kept.saturating_sub(4);
        let qf_noise = if qf_dof > 0 { qf.rms * (m_kept as f64 / qf_dof as f64).sqrt() } else { f64::NAN };
        let mut gamma1_sd = errors.map_or(f64::NAN, |e| e.0);
        // Only a window inside the contact sees the contact's own curvature.
        let mut curvature = errors.filter(|_| used_window <= radius).map(|e| (-qf.surface.mean_curvature(), e.1));
        let (mut gamma1, mut radius) = (gamma1, radius);
        // On a layer the paraboloid inside is not Hertz's: read through the
        // layer's own field, its peak and curvature give gamma1 and gamma1 /
        // a² (docs/sensing.md, "On a layer").
        if let Some(layer) = cfg.layer_shape()
            && let Some((g, a, ratio)) = through_layer(
                layer,
                gamma1,
                -qf.surface.mean_curvature(),
                radius,
                &MarkersFitted::of(&pts, &qf.kept, peak, cfg.isotropic),
            )
        {
            gamma1_sd *= g / gamma1;
            (gamma1, radius) = (g, a);
            curvature = curvature.map(|(c, sd)| (c / ratio, sd / ratio));
        }
        best = Some(Depth {
            gamma1,
            centre,
            radius,
            selected: sel,
            kept: qf.kept,
            rms: qf.rms,
            window: used_window,
            gamma1_sd,
            gamma1_common_sd: 0.0,
            noise_sd: qf_noise,
            dof: qf_dof,
            curvature,
            punch: None,
            adhesive: false,
        });
    }
    best.ok_or(SensingError::TooFewMarkers { index, stage: "quadratic fit", found: 0, needed: 7 })
}

/// The tied JKR fit ([`fit_tied_punch`]) over `pts`, its outliers rejected
/// by the same robust scale as the other fits and the fit repeated: the fit
/// and the markers it kept.
fn punch_stage(
    pts: &[[f64; 3]],
    centre: [f64; 2],
    c: f64,
    gamma1: f64,
    cfg: &SensingConfig,
) -> Option<(fit::PunchFit, Vec<bool>)> {
    let mut kept = vec![true; pts.len()];
    let mut fit = fit::fit_tied_punch(pts, cfg.layer_shape(), &kept, centre, c, gamma1)?;
    for _ in 0..3 {
        let resid: Vec<f64> = pts
            .iter()
            .map(|q| {
                let r = (q[0] - centre[0]).hypot(q[1] - centre[1]);
                let h = fit.gamma1 - fit.punch;
                let field = fit::field_shape(cfg.layer_shape(), r, fit.radius);
                (q[2] - h * field - fit.punch * fit::punch_shape(r / fit.radius)).abs()
            })
            .collect();
        let mut kr: Vec<f64> = resid.iter().zip(&kept).filter(|(_, k)| **k).map(|(e, _)| *e).collect();
        let limit = (cfg.outlier_sigmas * MAD_TO_SIGMA * median(&mut kr)).max(cfg.outlier_floor_mm);
        let next: Vec<bool> = resid.iter().map(|e| *e <= limit).collect();
        if next == kept || next.iter().filter(|&&b| b).count() < 5 {
            break;
        }
        kept = next;
        fit = fit::fit_tied_punch(pts, cfg.layer_shape(), &kept, centre, c, fit.gamma1)?;
    }
    Some((fit, kept))
}

/// Hertz-field fit over the markers within about three contact radii.
fn hertz_stage(frame: &SensorFrame, start: (f64, [f64; 2], f64), pitch: f64, cfg: &SensingConfig) -> Option<Depth> {
    let first = hertz_stage_sagged(frame, start, start.2, pitch, cfg)?;
    // The spheres' sag was taken at the starting radius: once more at the
    // radius found when that moved the sag at the edge by more than half a
    // micrometre, an eighth of a marker's noise (a punch widens the contact
    // its depth implies).
    let edge_sag = |a: f64| sim::sensor::field::spheres_sag_mm(a, a, cfg.indenter_radius_mm, cfg.elastomer_radius_mm);
    if (edge_sag(first.radius) - edge_sag(start.2)).abs() <= 5e-4 {
        return Some(first);
    }
    hertz_stage_sagged(frame, start, first.radius, pitch, cfg).or(Some(first))
}

/// [`hertz_stage`] with the spheres' sag taken for a contact of radius `sag_radius`.
fn hertz_stage_sagged(
    frame: &SensorFrame,
    start: (f64, [f64; 2], f64),
    sag_radius: f64,
    pitch: f64,
    cfg: &SensingConfig,
) -> Option<Depth> {
    let reach = (3.0 * start.2).max(3.0 * pitch);
    let selected: Vec<usize> =
        (0..frame.positions.len()).filter(|&i| dist2(xy(&frame.positions[i]), start.1) <= reach * reach).collect();
    if selected.len() < 6 {
        return None;
    }
    let pts: Vec<[f64; 3]> = selected
        .iter()
        .map(|&i| {
            let p = frame.positions[i];
            [p[0], p[1], hertz_depth(-frame.displacements[i][2], dist2(xy(&p), start.1).sqrt(), sag_radius, cfg)]
        })
        .collect();
    // Below about a pitch, gamma1 and a trade off along a long shallow
    // valley of the cost (markers mostly see the field outside the contact,
    // which depends on about gamma1 * a): refine the quadratic fit's estimate
    // locally when there is one, else start from a few radii and keep the
    // best fit. Far-apart minima can fit noisy markers equally well there.
    let curvature = match (cfg.contact_curvature_per_mm, cfg.max_curvature_per_mm) {
        (Some((per_mm, sd_per_mm)), _) if per_mm > 0.0 => Curvature::Known { per_mm, sd_per_mm },
        (_, Some(max_per_mm)) => Curvature::Bounded { max_per_mm, below_mm: pitch },
        _ => Curvature::Free,
    };
    // Known curvature and centre leave gamma1 alone to fit: one start.
    let fixed_centre = matches!(curvature, Curvature::Known { .. }) && cfg.contact_centre_mm == Some(start.1);
    let starts: &[f64] = if start.2 > 0.0 || fixed_centre { &[start.2] } else { &[0.3, 0.55, 0.9] };
    let hf = starts
        .iter()
        .map(|&a0| if start.2 > 0.0 || fixed_centre { a0 } else { a0 * pitch })
        .filter_map(|a0| {
            let (k, floor) = (cfg.outlier_sigmas, cfg.outlier_floor_mm);
            fit_hertz(&pts, cfg.layer_shape(), (start.0, start.1, a0), k, floor, curvature, fixed_centre)
        })
        .min_by(|x, y| {
            let score = |h: &fit::HertzFit| h.rms * (pts.len() as f64 / h.kept.iter().filter(|&&b| b).count() as f64);
            score(x).total_cmp(&score(y))
        })?;
    // An adhesive contact (JKR) is Hertz's field plus a flat punch's: the
    // same inside, steeper outside. With the curvature and centre known, a
    // tied fit that leaves more than chance in its residuals (a clean
    // frame's chi-square is about its dof) is tried again with a punch
    // (p <= 0), kept when the markers ask for it beyond chance
    // (docs/sensing.md, "Adhesive contacts").
    let noise = cfg.marker_noise_mm.map_or(hf.noise_sd, |n| n.0);
    let chi2 = |sse: f64| sse / (noise * noise);
    let sse_hertz = hf.rms * hf.rms * hf.kept.iter().filter(|&&b| b).count() as f64;
    let poor = noise > 0.0 && chi2(sse_hertz) > hf.dof as f64 + PUNCH_CHI2;
    // The tied fit rejects the markers a punch moves most (those inside the
    // contact read it 10-30 um above a tied Hertz field) as outliers when the
    // rest follow it: it is also tried when it left out markers.
    let rejected = hf.kept.iter().filter(|&&b| !b).count();
    // Only with the curvature known: before the run has learnt it, a free
    // curvature beside the punch reads these contacts no better (tried).
    // Only with the curvature known: before the run has learnt it, a punch
    // with a free curvature beside it reads these contacts no better (inside
    // a contact of a pitch or two the markers sit at one or two radii, where
    // depth and curvature trade off; docs/sensing.md).
    let punch = match curvature {
        Curvature::Known { per_mm, .. } if fixed_centre && (cfg.adhesive || poor || rejected >= 2) => {
            punch_stage(&pts, hf.centre, per_mm, hf.gamma1, cfg).filter(|(p, kept)| {
                // Both fields on the markers the punch kept.
                let hertz: f64 = pts
                    .iter()
                    .zip(kept)
                    .filter(|(_, k)| **k)
                    .map(|(q, _)| {
                        let r = (q[0] - hf.centre[0]).hypot(q[1] - hf.centre[1]);
                        (q[2] - hf.gamma1 * fit::field_shape(cfg.layer_shape(), r, hf.radius)).powi(2)
                    })
                    .sum();
                // On a gel known to be tacky the punch is the model: kept
                // whenever it pulls; else only beyond chance.
                p.punch < 0.0 && (cfg.adhesive || chi2(hertz - p.sse) > PUNCH_CHI2)
            })
        }
        _ => None,
    };
    if let Some((p, kept)) = punch {
        let m = kept.iter().filter(|&&b| b).count();
        let dof = m.saturating_sub(1);
        let rms = (p.sse / m as f64).sqrt();
        let noise_sd = if dof > 0 { rms * (m as f64 / dof as f64).sqrt() } else { f64::NAN };
        let own = p.gamma1_sd_per_noise * noise_sd;
        let here = dist2(hf.centre, start.1) <= reach * reach && p.gamma1 > 0.0 && p.radius > 0.0;
        // Its curvature is the one it was given: nothing to learn from it.
        return here.then(|| Depth {
            gamma1: p.gamma1,
            centre: hf.centre,
            radius: p.radius,
            selected,
            kept,
            rms,
            window: 0.0,
            gamma1_sd: own.hypot(hf.gamma1_common_sd),
            gamma1_common_sd: hf.gamma1_common_sd,
            noise_sd,
            dof,
            curvature: None,
            punch: Some(p.punch),
            adhesive: true,
        });
    }
    // A contact over about a pitch and a sixth, at a known centre, holds
    // enough markers inside it to measure its curvature with the radius
    // free: that is learnt (by [`FrameEstimator`]) where it is used, below
    // the contacts a paraboloid resolves. gamma1 stays the tied fit's. A
    // tied fit the field does not follow (poor) teaches nothing: a Hertz
    // curvature fitted to another field is not the contact's.
    let curvature = if fixed_centre && !poor && hf.radius >= MID_CONTACT_PITCHES * pitch {
        let (k, floor) = (cfg.outlier_sigmas, cfg.outlier_floor_mm);
        fit_hertz(&pts, cfg.layer_shape(), (hf.gamma1, hf.centre, hf.radius), k, floor, Curvature::Free, true)
            .filter(|f| (0.7..=1.4).contains(&(f.radius / hf.radius)))
            .and_then(|f| {
                f.curvature_sd.filter(|sd| sd.is_finite() && *sd > 0.0).map(|sd| (f.gamma1 / (f.radius * f.radius), sd))
            })
    } else {
        None
    };
    // The fit must stay where it started, not wander off to another bump.
    if dist2(hf.centre, start.1) > reach * reach || !(hf.gamma1 > 0.0 && hf.radius > 0.0) {
        return None;
    }
    Some(Depth {
        gamma1: hf.gamma1,
        centre: hf.centre,
        radius: hf.radius,
        selected,
        kept: hf.kept,
        rms: hf.rms,
        window: 0.0,
        gamma1_sd: hf.gamma1_sd,
        gamma1_common_sd: hf.gamma1_common_sd,
        noise_sd: hf.noise_sd,
        dof: hf.dof,
        curvature,
        punch: None,
        adhesive: false,
    })
}

/// Measure gamma1, theta1 and the contact from one frame.
pub fn measure(frame: &SensorFrame, cfg: &SensingConfig) -> Result<Measurement, SensingError> {
    validate(frame)?;
    let index = frame.index;
    let n = frame.positions.len();
    // A real Tac3D reports exact zeros without contact (a dead band).
    if frame.displacements.iter().all(|d| *d == [0.0; 3]) {
        return Err(SensingError::NoContact { index, depth_mm: 0.0 });
    }
    let (seed, seed_depth, pitch) = deepest_marker(frame);
    if seed_depth.is_nan() || seed_depth < cfg.min_depth_mm {
        return Err(SensingError::NoContact { index, depth_mm: seed_depth.max(0.0) });
    }
    let pitch = if pitch.is_finite() && pitch > 0.0 { pitch } else { 1.0 };
    let quad = quadratic_stage(frame, seed, pitch, cfg);
    // The paraboloid is Hertz's field only inside the contact: when the
    // smallest usable window reaches outside it (a contact under ~1.5
    // pitches), or no paraboloid fits at all, fit the Hertz field itself.
    // A paraboloid over markers outside a small contact sees a flatter field
    // and so a wider contact: with the curvature known, the depth says how
    // wide the contact is.
    let implied_radius = |d: &Depth| match cfg.contact_curvature_per_mm {
        Some((c, _)) if c > 0.0 => d.radius.min((d.gamma1 / c).sqrt()),
        _ => d.radius,
    };
    let needs_hertz = cfg.hertz_refine
        && match &quad {
            Ok(d) => d.window > implied_radius(d),
            Err(_) => true,
        };
    let depth = if needs_hertz {
        let start = match (&quad, cfg.contact_curvature_per_mm, cfg.contact_centre_mm) {
            // The contact's curvature and place are known: only its depth is not.
            (_, Some((c, _)), Some(centre)) if c > 0.0 => {
                let g = quad.as_ref().map_or(seed_depth, |d| d.gamma1).max(cfg.min_depth_mm);
                (g, centre, (g / c).sqrt())
            }
            (Ok(d), ..) => (d.gamma1, d.centre, d.radius.min(2.0 * pitch)),
            // No usable paraboloid: multi-start (radius 0 asks for it).
            (Err(_), ..) => (seed_depth, xy(&frame.positions[seed]), 0.0),
        };
        let h = hertz_stage(frame, start, pitch, cfg);
        match h {
            Some(d) => d,
            None => quad?,
        }
    } else {
        let d = quad?;
        // A resolved contact reads its depth right whatever the punch; while
        // the run has not decided whether the gel is tacky, it is asked too.
        match (cfg.probe_adhesion, cfg.contact_curvature_per_mm, cfg.contact_centre_mm) {
            (true, Some((c, _)), Some(at)) if c > 0.0 && d.radius < PROBE_PITCHES * pitch => {
                Depth { adhesive: adhesion_probe(frame, at, c, d.gamma1, d.radius.max(pitch), cfg), ..d }
            }
            _ => d,
        }
    };
    let Depth {
        gamma1,
        centre,
        radius,
        selected,
        kept: depth_kept,
        rms: depth_rms,
        gamma1_sd,
        gamma1_common_sd,
        curvature,
        noise_sd,
        dof,
        punch,
        adhesive,
        ..
    } = depth;
    // The errors with the pooled marker noise (the tie's part is not noise).
    let noise_scale = {
        let own = noise_sd;
        let used = noise_for_errors(own, cfg.marker_noise_mm.map(|n| n.0));
        if own.is_finite() && own > 0.0 && used.is_finite() { used / own } else { 1.0 }
    };
    let gamma1_sd = (gamma1_sd * gamma1_sd - gamma1_common_sd * gamma1_common_sd).max(0.0).sqrt() * noise_scale;
    let gamma1_sd = gamma1_sd.hypot(gamma1_common_sd);
    let curvature = curvature.map(|(c, sd)| (c, sd * noise_scale));
    if gamma1.is_nan() || gamma1 < cfg.min_depth_mm {
        return Err(SensingError::NoContact { index, depth_mm: gamma1.max(0.0) });
    }
    if !(radius.is_finite() && radius > 0.0) {
        return Err(SensingError::NoPeak { index, marker: seed });
    }

    // Rotation of the stick region about the contact centre.
    let stick_r = cfg.stick_fraction * radius;
    let mut stick: Vec<usize> =
        (0..n).filter(|&i| dist2(xy(&frame.positions[i]), centre) <= stick_r * stick_r).collect();
    let need = cfg.min_stick_markers.max(2);
    if stick.len() < need {
        let mut by_dist: Vec<usize> = (0..n).collect();
        by_dist.sort_by(|&a, &b| {
            dist2(xy(&frame.positions[a]), centre).total_cmp(&dist2(xy(&frame.positions[b]), centre))
        });
        stick = by_dist.into_iter().take(need).collect();
    }
    if stick.len() < 2 {
        return Err(SensingError::TooFewMarkers { index, stage: "rotation fit", found: stick.len(), needed: 2 });
    }
    let p: Vec<[f64; 2]> = stick.iter().map(|&i| xy(&frame.positions[i])).collect();
    let q: Vec<[f64; 2]> = stick
        .iter()
        .map(|&i| {
            let (pp, d) = (frame.positions[i], frame.displacements[i]);
            [pp[0] + d[0], pp[1] + d[1]]
        })
        .collect();
    let rf = fit_rotation(&p, &q, centre, cfg.outlier_sigmas, cfg.outlier_floor_mm)
        .ok_or(SensingError::TooFewMarkers { index, stage: "rotation fit", found: stick.len(), needed: 2 })?;

    let mut used = vec![false; n];
    let mut rejected = vec![false; n];
    for (&i, &kept) in selected.iter().zip(&depth_kept) {
        if kept {
            used[i] = true;
        } else {
            rejected[i] = true;
        }
    }
    for (&i, &kept) in stick.iter().zip(&rf.kept) {
        if kept {
            used[i] = true;
        } else {
            rejected[i] = true;
        }
    }
    let stick_markers = rf.kept.iter().filter(|&&b| b).count();
    // The tangential noise: the residual rms less the one parameter (theta).
    let rotation_dof = stick_markers.saturating_sub(1);
    let rotation_noise =
        if rotation_dof > 0 { rf.rms * (stick_markers as f64 / rotation_dof as f64).sqrt() } else { f64::NAN };
    let theta_std = rf.theta_sd(noise_for_errors(rotation_noise, cfg.marker_noise_mm.map(|n| n.1)));
    Ok(Measurement {
        index,
        t_s: frame.t_s,
        gamma1_mm: gamma1,
        theta1_deg: rf.theta.to_degrees(),
        gamma1_sd_mm: gamma1_sd,
        gamma1_common_sd_mm: gamma1_common_sd,
        depth_noise_mm: noise_sd,
        depth_dof: dof,
        rotation_noise_mm: rotation_noise,
        rotation_dof,
        contact_curvature_per_mm: curvature,
        punch_mm: punch,
        adhesive,
        contact_centre_mm: centre,
        contact_radius_mm: radius,
        gamma1_residual_mm: depth_rms,
        theta1_residual_mm: rf.rms,
        theta1_std_deg: theta_std.to_degrees(),
        depth_markers: depth_kept.iter().filter(|&&b| b).count(),
        stick_markers,
        markers_used: used.iter().filter(|&&b| b).count(),
        outliers: rejected.iter().filter(|&&b| b).count(),
    })
}

/// A software zero for links that cannot re-zero the sensor itself: the
/// displacements of an untouched frame, subtracted from later frames.
#[derive(Debug, Clone, PartialEq)]
pub struct Tare {
    offsets: Vec<[f64; 3]>,
}

impl Tare {
    /// Take `frame` (sensor untouched) as the zero.
    pub fn from_frame(frame: &SensorFrame) -> Result<Self, SensingError> {
        validate(frame)?;
        Ok(Self { offsets: frame.displacements.clone() })
    }

    /// `frame` with the zero subtracted. Markers the sensor reports as exactly
    /// zero stay zero (its dead band: no contact must still read no contact).
    pub fn apply(&self, frame: &SensorFrame) -> Result<SensorFrame, SensingError> {
        validate(frame)?;
        if frame.displacements.len() != self.offsets.len() {
            return Err(SensingError::LengthMismatch {
                index: frame.index,
                positions: self.offsets.len(),
                displacements: frame.displacements.len(),
            });
        }
        let mut out = frame.clone();
        if frame.displacements.iter().all(|d| *d == [0.0; 3]) {
            return Ok(out);
        }
        for (d, o) in out.displacements.iter_mut().zip(&self.offsets) {
            for (v, z) in d.iter_mut().zip(o) {
                *v -= z;
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::sensor::shape::SurfaceShape;

    /// A 1 mm grid's markers within `window` of `centre`, relative to it.
    fn markers(centre: [f64; 2], window: f64) -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        for i in -8..=8 {
            for j in -8..=8 {
                let (x, y) = (i as f64 - centre[0], j as f64 - centre[1]);
                if x.hypot(y) <= window {
                    v.push([x, y, 0.0]);
                }
            }
        }
        v
    }

    /// Without a departure the field inside the contact is Hertz's
    /// paraboloid, 1 - r² / 2a², which any marker set reads exactly: peak 1
    /// and curvature 1 (per gamma1 and per 1 / a²), centred or not.
    #[test]
    fn hertzs_own_field_reads_as_its_paraboloid_at_any_markers() {
        let flat = SurfaceShape::new(vec![1.0, 2.0], 0.5, vec![vec![0.0; 21]; 2]).unwrap();
        for (centre, isotropic) in [([0.0, 0.0], true), ([0.3, -0.2], true), ([0.3, -0.2], false)] {
            let pts = markers(centre, 3.2);
            let fitted = MarkersFitted::of(&pts, &vec![true; pts.len()], [0.0, 0.0], isotropic);
            let (peak, curvature) = fitted.paraboloid_of(&flat, 4.0).unwrap();
            assert!((peak - 1.0).abs() < 1e-12 && (curvature - 1.0).abs() < 1e-12, "{peak} {curvature}");
        }
        let pts = markers([0.0, 0.0], 2.0);
        assert!(MarkersFitted::of(&pts, &vec![true; pts.len()], [0.0, 0.0], true).paraboloid_of(&flat, 0.0).is_none());
    }

    /// A departure that is itself a paraboloid inside, -e r² / a², steepens
    /// the read curvature by 2e and leaves the peak; a quartic one, -e r⁴ /
    /// a⁴, is read as the paraboloid of the markers' own least squares at
    /// their radii, whatever a continuous disc would weigh them by.
    #[test]
    fn a_departure_is_read_as_the_markers_own_least_squares_take_it() {
        let rows = |f: fn(f64) -> f64| {
            [1.0f64, 2.0].map(|a| (0..=500).map(|j| f(0.02 * j as f64 / a)).collect::<Vec<_>>()).to_vec()
        };
        let e = 0.05;
        let steep = SurfaceShape::new(vec![1.0, 2.0], 0.02, rows(|rho| -0.05 * rho * rho)).unwrap();
        let pts = markers([0.0, 0.0], 1.6);
        let fitted = MarkersFitted::of(&pts, &vec![true; pts.len()], [0.0, 0.0], true);
        let (peak, curvature) = fitted.paraboloid_of(&steep, 2.0).unwrap();
        assert!((peak - 1.0).abs() < 1e-4 && (curvature - (1.0 + 2.0 * e)).abs() < 1e-4, "{peak} {curvature}");
        // The quartic, by hand: least squares of 1 - q r² to -e (r / a)⁴ at
        // the markers' radii (isotropic, symmetric set: the tilt drops out).
        let quartic = SurfaceShape::new(vec![1.0, 2.0], 0.02, rows(|rho| -0.05 * rho.powi(4))).unwrap();
        let a = 2.0;
        let pts = markers([0.0, 0.0], 1.6);
        let r2: Vec<f64> = pts.iter().map(|p| p[0] * p[0] + p[1] * p[1]).collect();
        let f: Vec<f64> = r2.iter().map(|x| 1.0 - x / (2.0 * a * a) - e * x * x / a.powi(4)).collect();
        let n = r2.len() as f64;
        let (sx, sxx) = (r2.iter().sum::<f64>(), r2.iter().map(|x| x * x).sum::<f64>());
        let (sf, sxf) = (f.iter().sum::<f64>(), r2.iter().zip(&f).map(|(x, y)| x * y).sum::<f64>());
        let det = n * sxx - sx * sx;
        let want_peak = (sf * sxx - sxf * sx) / det;
        let want_curvature = -2.0 * (n * sxf - sx * sf) / det * a * a;
        let fitted = MarkersFitted::of(&pts, &vec![true; pts.len()], [0.0, 0.0], true);
        let (peak, curvature) = fitted.paraboloid_of(&quartic, a).unwrap();
        assert!(
            (peak - want_peak).abs() < 1e-3 * e && (curvature - want_curvature).abs() < 1e-3 * e,
            "{peak} {curvature}"
        );
        // The quartic lifts the peak (a concave part fitted by a line in r²).
        assert!(want_peak > 1.0 + 0.01 * e, "{want_peak}");
    }
}
