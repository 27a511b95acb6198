//! The estimator a run reads its frames through: [`measure`] plus what the
//! run's own frames teach it. Contacts smaller than about one marker pitch
//! cannot tell their depth from their radius (docs/sensing.md, "Small
//! contacts"); contacts a few pitches wide measure the field's curvature
//! inside the contact, gamma1 / a^2, directly. In a Hertz contact that
//! curvature is the same at every depth (gamma1 = f1 delta and a^2 = R delta,
//! so gamma1 / a^2 = f1 / R, f1 the elastomer's share of the approach), so
//! the curvature learnt on resolved contacts settles the small ones.

use devices::sensor::SensorFrame;

use super::layer::{DRIFT_SD_FRACTION, TieDrift};
use super::{Measurement, SensingConfig, SensingError, measure};
use crate::numerics::stats::MAD_TO_SIGMA;

/// Resolved frames whose curvature is kept: the approach and the start of
/// the sweep give them; the curvature is learnt by then.
const MAX_ESTIMATES: usize = 400;

/// Fewest resolved frames before the curvature is used.
const MIN_ESTIMATES: usize = 5;

/// Estimates from contacts up to this multiple of the smallest resolved ones
/// are averaged: the curvature is applied below that size, and in a real
/// (layered, large-strain) contact it drifts slowly with depth.
const RADIUS_SPAN: f64 = 1.5;

/// An estimate further than this many robust sigmas from the others' median
/// (curvature or centre) is a frame that only looked resolved (a noisy
/// paraboloid over a small contact) and is left out.
const OUTLIER_SIGMAS: f64 = 4.0;

/// A contact of radius r is fitted with the curvature learnt on resolved
/// contacts within this factor of r either way, when there are enough of them
/// on both sides of r ([`MIN_LOCAL`]): the curvature drifts with depth
/// (Tatara's large deformation: about 0.8 % between contacts of 0.9 and 1.6 mm
/// on the default rig, a micrometre of gamma1 at 1.5 mm), so it is taken where
/// it is used, from a straight line in the radius through those estimates.
const LOCAL_SPAN: f64 = 1.5;

/// Fewest estimates near a radius (and a quarter of that on each side of it)
/// before they alone give its curvature.
const MIN_LOCAL: usize = 24;

/// Width of the radius bins the local estimates are kept in, mm, and how many
/// each bin keeps (the first ones: a sweep revisits each size).
const BIN_MM: f64 = 0.05;
const PER_BIN: usize = 60;

/// One resolved frame: contact radius mm, curvature 1/mm, its standard
/// error 1/mm, centre mm.
type Estimate = (f64, f64, f64, [f64; 2]);

/// The field's curvature inside the contact and where the contact is, learnt
/// from resolved frames.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CurvatureLearner {
    estimates: Vec<Estimate>,
    /// (curvature, its standard error, centre, mean radius) from the
    /// estimates so far.
    learnt: Option<(f64, f64, [f64; 2], f64)>,
    /// Every size's estimates, by radius bin (index = radius / [`BIN_MM`]).
    bins: std::collections::BTreeMap<i64, Vec<Estimate>>,
    /// How many estimates the bins hold (they only grow).
    binned: usize,
    /// On a declared layer, how the curvature changes with the contact's
    /// radius: a curvature learnt at one size is carried by it to another.
    drift: Option<TieDrift>,
}

impl CurvatureLearner {
    /// A learner on a declared gel layer, whose curvature changes with the
    /// contact's radius as `drift` says (docs/sensing.md, "On a layer").
    pub fn with_drift(drift: Option<TieDrift>) -> Self {
        Self { drift, ..Self::default() }
    }

    /// Carry the curvatures learnt so far by another drift (the run has
    /// learnt where its gel lies in the layer's family).
    fn set_drift(&mut self, drift: Option<TieDrift>) {
        self.drift = drift;
    }

    /// A curvature (and its standard error) measured at radius `from_mm`,
    /// carried to `to_mm` by the layer's drift, the drift's own uncertainty
    /// added; unchanged on a half-space.
    fn carried(&self, (c, sd): (f64, f64), from_mm: f64, to_mm: f64) -> (f64, f64) {
        match self.drift {
            Some(d) => {
                let k = d.ratio(from_mm, to_mm);
                (c * k, (sd * k).hypot(c * (k - 1.0).abs() * DRIFT_SD_FRACTION))
            }
            None => (c, sd),
        }
    }

    /// Take one resolved frame's curvature `per_mm` (standard error
    /// `sd_per_mm`) at contact radius `radius_mm`, centred at `centre_mm`;
    /// non-physical ones are ignored.
    pub fn add(&mut self, radius_mm: f64, per_mm: f64, sd_per_mm: f64, centre_mm: [f64; 2]) {
        let ok = [radius_mm, per_mm, sd_per_mm].iter().all(|v| v.is_finite() && *v > 0.0)
            && centre_mm.iter().all(|v| v.is_finite());
        if !ok {
            return;
        }
        let e = (radius_mm, per_mm, sd_per_mm, centre_mm);
        if self.estimates.len() < MAX_ESTIMATES {
            self.estimates.push(e);
            self.learnt = learn(&self.estimates);
        }
        let bin = self.bins.entry((radius_mm / BIN_MM).floor() as i64).or_default();
        if bin.len() < PER_BIN {
            bin.push(e);
            self.binned += 1;
        }
    }

    /// The curvature for a contact of about `radius_mm`: from the resolved
    /// contacts of about that size when there are enough ([`LOCAL_SPAN`]),
    /// else [`CurvatureLearner::estimate`] (the smallest resolved ones, for
    /// contacts smaller than any resolved).
    pub fn estimate_near(&self, radius_mm: f64) -> Option<(f64, f64)> {
        // Below (above) every resolved size, the curvature at the edge of
        // what was resolved: a line is not extrapolated (on a declared layer
        // the layer's drift carries it on).
        let wanted = radius_mm;
        let radius_mm = match self.resolved_span() {
            Some((lo, hi)) => radius_mm.clamp(lo, hi),
            None => radius_mm,
        };
        let local = (radius_mm.is_finite() && radius_mm > 0.0)
            .then(|| {
                let (lo, hi) = (radius_mm / LOCAL_SPAN, radius_mm * LOCAL_SPAN);
                let range = (lo / BIN_MM).floor() as i64..=(hi / BIN_MM).floor() as i64;
                let near: Vec<(f64, &Estimate)> = self
                    .bins
                    .range(range)
                    .flat_map(|(_, v)| {
                        // Weights from the bin's typical error, not each
                        // estimate's own: a frame's error grows with its
                        // curvature, and weighting by it would pull the mean low.
                        let mut sds: Vec<f64> = v.iter().map(|e| e.2).collect();
                        let typical = quantile(&mut sds, 0.5).unwrap_or(f64::NAN);
                        v.iter().map(move |e| (typical, e))
                    })
                    .filter(|(_, e)| (lo..=hi).contains(&e.0))
                    .collect();
                let (below, above) =
                    near.iter().fold((0, 0), |(b, a), (_, e)| if e.0 < radius_mm { (b + 1, a) } else { (b, a + 1) });
                let enough = near.len() >= MIN_LOCAL && below.min(above) >= MIN_LOCAL / 4;
                enough.then(|| local_line(&near, radius_mm)).flatten()
            })
            .flatten();
        // Too few on one side for a line: the mean of the sizes near it, at
        // their own mean radius; only without those, the smallest contacts'.
        // (Those are the lower fifth of every estimate, which a long hold of
        // deep frames — the torsion sweep — fills: a contact that shrinks
        // back after it would take the deepest contact's curvature, 12 %
        // off on a layer; docs/sensing.md, "What a run learns".)
        let (c, sd, at) = match local {
            Some((c, sd)) => (c, sd, radius_mm),
            None => self.nearby(radius_mm).or(self.learnt.map(|l| (l.0, l.1, l.3)))?,
        };
        Some(self.carried((c, sd), at, wanted))
    }

    /// The robust weighted mean of the estimates within [`LOCAL_SPAN`] of
    /// `radius_mm` (curvature, standard error, their mean radius), when
    /// [`MIN_ESTIMATES`] are left.
    fn nearby(&self, radius_mm: f64) -> Option<(f64, f64, f64)> {
        if !(radius_mm.is_finite() && radius_mm > 0.0) {
            return None;
        }
        let (lo, hi) = (radius_mm / LOCAL_SPAN, radius_mm * LOCAL_SPAN);
        let range = (lo / BIN_MM).floor() as i64..=(hi / BIN_MM).floor() as i64;
        let near: Vec<&Estimate> =
            self.bins.range(range).flat_map(|(_, v)| v.iter()).filter(|e| (lo..=hi).contains(&e.0)).collect();
        let (c, sd, _, at) = weighted(&robust_subset(&near)?)?;
        Some((c, sd, at))
    }

    /// The curvature and its standard error (see [`learn`]); `None` before
    /// enough frames.
    pub fn estimate(&self) -> Option<(f64, f64)> {
        self.learnt.map(|l| (l.0, l.1))
    }

    /// Where the smallest resolved contacts were centred.
    pub fn centre(&self) -> Option<[f64; 2]> {
        self.learnt.map(|l| l.2)
    }
}

/// The inverse-variance weighted curvature of the smallest resolved contacts
/// (those within [`RADIUS_SPAN`] of the lower fifth of the radii), with its
/// standard error widened by the Birge ratio when they disagree beyond their
/// errors (a drift with depth, a model the frames do not follow), and their
/// mean centre. Frames far from the others' median are left out first.
fn learn(estimates: &[Estimate]) -> Option<(f64, f64, [f64; 2], f64)> {
    let mut radii: Vec<f64> = estimates.iter().map(|e| e.0).collect();
    let smallest = quantile(&mut radii, 0.2)?;
    let near: Vec<&Estimate> = estimates.iter().filter(|e| e.0 <= RADIUS_SPAN * smallest).collect();
    weighted(&robust_subset(&near)?)
}

/// The estimates within [`OUTLIER_SIGMAS`] robust sigmas of the others'
/// median in curvature and in centre; `None` when fewer than
/// [`MIN_ESTIMATES`] are left.
fn robust_subset<'e>(near: &[&'e Estimate]) -> Option<Vec<&'e Estimate>> {
    let robust = |v: Vec<f64>| -> Option<(f64, f64)> {
        let mut v = v;
        let med = quantile(&mut v, 0.5)?;
        let mut dev: Vec<f64> = v.iter().map(|x| (x - med).abs()).collect();
        Some((med, MAD_TO_SIGMA * quantile(&mut dev, 0.5)?))
    };
    let (c_med, c_sigma) = robust(near.iter().map(|e| e.1).collect())?;
    let (x_med, x_sigma) = robust(near.iter().map(|e| e.3[0]).collect())?;
    let (y_med, y_sigma) = robust(near.iter().map(|e| e.3[1]).collect())?;
    // A hundredth of a millimetre of centre, a percent of curvature: below
    // that, agreement is not worth a test.
    let within = |x: f64, med: f64, sigma: f64, floor: f64| (x - med).abs() <= OUTLIER_SIGMAS * sigma.max(floor);
    let kept: Vec<&Estimate> = near
        .iter()
        .copied()
        .filter(|e| {
            within(e.1, c_med, c_sigma, 0.01 * c_med)
                && within(e.3[0], x_med, x_sigma, 0.01)
                && within(e.3[1], y_med, y_sigma, 0.01)
        })
        .collect();
    (kept.len() >= MIN_ESTIMATES).then_some(kept)
}

/// The inverse-variance weighted curvature of `kept`, its standard error
/// widened by the Birge ratio, their mean centre and their radius (weighted
/// as the curvature is).
fn weighted(kept: &[&Estimate]) -> Option<(f64, f64, [f64; 2], f64)> {
    if kept.len() < 2 {
        return None;
    }
    let w: f64 = kept.iter().map(|e| 1.0 / (e.2 * e.2)).sum();
    let mean = kept.iter().map(|e| e.1 / (e.2 * e.2)).sum::<f64>() / w;
    let chi2 = kept.iter().map(|e| ((e.1 - mean) / e.2).powi(2)).sum::<f64>();
    let birge = (chi2 / (kept.len() - 1) as f64).sqrt().max(1.0);
    let n = kept.len() as f64;
    let centre = [kept.iter().map(|e| e.3[0]).sum::<f64>() / n, kept.iter().map(|e| e.3[1]).sum::<f64>() / n];
    let radius = kept.iter().map(|e| e.0 / (e.2 * e.2)).sum::<f64>() / w;
    Some((mean, birge / w.sqrt(), centre, radius))
}

impl CurvatureLearner {
    /// The radii between which a local line has [`MIN_LOCAL`] / 4 estimates
    /// on each side: the (MIN_LOCAL / 4)-th smallest and largest radius.
    fn resolved_span(&self) -> Option<(f64, f64)> {
        if self.binned < MIN_LOCAL {
            return None;
        }
        // The k-th radius from one end: walk the bins from that end to the one
        // holding it, and sort that bin alone.
        let kth = |bins: &mut dyn Iterator<Item = &Vec<Estimate>>, from_top: bool| -> Option<f64> {
            let mut k = MIN_LOCAL / 4;
            for v in bins {
                if k < v.len() {
                    let mut r: Vec<f64> = v.iter().map(|e| e.0).collect();
                    r.sort_by(f64::total_cmp);
                    return Some(if from_top { r[r.len() - 1 - k] } else { r[k] });
                }
                k -= v.len();
            }
            None
        };
        Some((kth(&mut self.bins.values(), false)?, kth(&mut self.bins.values().rev(), true)?))
    }
}

/// The curvature at `radius_mm` and its standard error from a weighted
/// straight line c = b0 + b1 (r - radius_mm) through `near` ((typical error,
/// estimate) pairs), after leaving out estimates far from the others' median;
/// the error is widened by the Birge ratio. `None` when degenerate.
fn local_line(near: &[(f64, &Estimate)], radius_mm: f64) -> Option<(f64, f64)> {
    let mut cs: Vec<f64> = near.iter().map(|(_, e)| e.1).collect();
    let med = quantile(&mut cs, 0.5)?;
    let mut dev: Vec<f64> = cs.iter().map(|c| (c - med).abs()).collect();
    let sigma = (MAD_TO_SIGMA * quantile(&mut dev, 0.5)?).max(0.01 * med);
    let kept: Vec<(f64, f64, f64)> = near
        .iter()
        .filter(|(sd, e)| sd.is_finite() && *sd > 0.0 && (e.1 - med).abs() <= OUTLIER_SIGMAS * sigma)
        .map(|(sd, e)| (e.0 - radius_mm, e.1, 1.0 / (sd * sd)))
        .collect();
    if kept.len() < MIN_LOCAL {
        return None;
    }
    let (mut sw, mut sx, mut sxx, mut sy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(x, y, w) in &kept {
        (sw, sx, sxx, sy, sxy) = (sw + w, sx + w * x, sxx + w * x * x, sy + w * y, sxy + w * x * y);
    }
    let det = sw * sxx - sx * sx;
    if !(det.is_finite() && det > 0.0) {
        return None;
    }
    let (b0, b1) = ((sxx * sy - sx * sxy) / det, (sw * sxy - sx * sy) / det);
    let chi2: f64 = kept.iter().map(|&(x, y, w)| w * (y - b0 - b1 * x).powi(2)).sum();
    let birge = (chi2 / (kept.len() - 2) as f64).sqrt().max(1.0);
    let se = birge * (sxx / det).sqrt();
    (b0.is_finite() && b0 > 0.0 && se.is_finite()).then_some((b0, se))
}

/// The `p` quantile (nearest rank) of `v`, reordering it; `None` when empty.
fn quantile(v: &mut [f64], p: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let k = ((v.len() - 1) as f64 * p).round() as usize;
    let (_, x, _) = v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    Some(*x)
}

/// [`measure`] with the curvature learnt from this run's resolved frames
/// (unless the configuration fixes one).
#[derive(Debug, Clone)]
pub struct FrameEstimator {
    cfg: SensingConfig,
    learner: CurvatureLearner,
    /// The marker noise of the recent frames: normal and tangential.
    normal_noise: NoisePool,
    tangential_noise: NoisePool,
    /// The last frame's contact radius, mm: the next frame's contact is about
    /// as large (a sample reads several frames at one stage position), so its
    /// curvature is the one learnt at that size.
    last_radius_mm: Option<f64>,
    /// The curvature at the last radius, with the radius bin and the count of
    /// binned estimates it was computed for: kept while neither moves much.
    near: Option<NearCurvature>,
    /// Of the latest measured contacts (at most [`ADHESIVE_WINDOW`]), which
    /// were read as adhesive beyond chance, newest last.
    adhesive_recent: std::collections::VecDeque<bool>,
    /// Set for good once [`ADHESIVE_FRAMES`] of the latest
    /// [`ADHESIVE_WINDOW`] contacts read adhesive.
    tacky: bool,
    /// Frames measured while probing for adhesion.
    probes: usize,
    /// The latest frames measured while probing for adhesion but before the
    /// run knew the contact's curvature (the approach's), at most
    /// [`ADHESIVE_WINDOW`]: probed once it is known.
    unprobed: std::collections::VecDeque<SensorFrame>,
    /// On a declared layer of unknown gel, the weights between the family's
    /// two gels the resolved frames gave ([`super::layer_weight`]), and the
    /// contacts measured while they were being learnt.
    layer_weights: Vec<f64>,
    layer_tries: usize,
}

/// A curvature computed at a radius bin with so many binned estimates.
#[derive(Debug, Clone, Copy, PartialEq)]
struct NearCurvature {
    bin: i64,
    binned: usize,
    curvature: Option<(f64, f64)>,
}

/// Frames read as adhesive beyond chance (each a chi-square drop of 16 for
/// one parameter), among the latest [`ADHESIVE_WINDOW`] measured contacts,
/// before the gel is taken as tacky and every small contact at the known
/// centre is fitted with the punch. A count over the whole run is not enough:
/// on a Hertz contact of 1.6-2.2 mm the probe reads "adhesive" in a few
/// percent of frames (model mismatch, not chance), so a clean gel reached ten
/// after ~150 probed frames or not depending on how many frames of that size
/// the run happened to measure, which depends on the machine's load (seed 4
/// of the frame-compliance rig test did, and read every later small contact
/// with a punch). A tacky gel shows it on most frames in a row.
const ADHESIVE_FRAMES: usize = 10;

/// The run of latest measured contacts [`ADHESIVE_FRAMES`] is counted in.
const ADHESIVE_WINDOW: usize = 20;

/// Frames measured with the probe for adhesion on (a run's approach and the
/// start of its sweep), after which a gel not shown tacky is taken as not.
const MAX_PROBES: usize = 600;

/// A frame whose contact radius differs from the last frame's by more than
/// this (in log) is read again with the curvature learnt at its own size: 5 %
/// of radius, where a layer's tie drifts by about 0.5 %.
const RESIZED: f64 = 0.05;

/// New estimates a cached curvature outlives (a few percent of a full window).
const NEAR_STALE: usize = 8;

/// Resolved frames whose layer weight is learnt (docs/sensing.md, "On a
/// layer"): their median is taken from [`LAYER_WEIGHT_MIN`] on, and the
/// weight is settled at [`LAYER_WEIGHT_FRAMES`]. A run's approach gives
/// about fourteen.
const LAYER_WEIGHT_FRAMES: usize = 12;
const LAYER_WEIGHT_MIN: usize = 5;

/// Contacts measured before a layer's weight is taken as settled at the
/// middle of its family when too few were of a size that shows it.
const LAYER_WEIGHT_PATIENCE: usize = 60;

/// Contact radii whose field shows where the gel lies in the layer's family,
/// mm: a pitch or more (markers inside and out) and well inside the grid.
const LAYER_WEIGHT_RADII_MM: (f64, f64) = (0.9, 3.0);

impl FrameEstimator {
    pub fn new(cfg: SensingConfig) -> Self {
        Self {
            learner: CurvatureLearner::with_drift(cfg.layer.as_ref().map(|l| l.drift)),
            cfg,
            normal_noise: NoisePool::default(),
            tangential_noise: NoisePool::default(),
            last_radius_mm: None,
            near: None,
            adhesive_recent: std::collections::VecDeque::with_capacity(ADHESIVE_WINDOW),
            tacky: false,
            probes: 0,
            layer_weights: Vec::new(),
            layer_tries: 0,
            unprobed: std::collections::VecDeque::new(),
        }
    }

    /// Count one measured contact's adhesion evidence towards the decision.
    fn weigh_adhesion(&mut self, adhesive: bool) {
        if self.tacky {
            return;
        }
        if self.adhesive_recent.len() == ADHESIVE_WINDOW {
            self.adhesive_recent.pop_front();
        }
        self.adhesive_recent.push_back(adhesive);
        self.tacky = self.adhesive_recent.iter().filter(|&&a| a).count() >= ADHESIVE_FRAMES;
    }

    /// Probe the frames kept from before the curvature was known, now that
    /// it is (`cfg` carries it): a run's approach presses the gel once, to
    /// about half a millimetre, before its deepest frames teach the
    /// curvature, and a tacky gel shows its punch there. Probed late, those
    /// frames decide before the sweep, whose first contacts are too small to
    /// show it (docs/sensing.md, "Adhesive contacts").
    fn probe_kept(&mut self, cfg: &SensingConfig) {
        while let Some(frame) = self.unprobed.pop_front() {
            if self.tacky || self.probes >= MAX_PROBES {
                self.unprobed.clear();
                return;
            }
            if let Some(adhesive) = super::shows_punch(&frame, cfg) {
                self.probes += 1;
                self.weigh_adhesion(adhesive);
            }
        }
    }

    /// Whether the field's shape is settled: a half-space, a layer of known
    /// gel, or a layer whose weight in its family the run has learnt (or
    /// given up learning: too few contacts of a size that shows it).
    fn layer_settled(&self) -> bool {
        let family = self.cfg.layer.as_ref().and_then(|l| l.family.as_ref());
        family.is_none() || self.layer_weights.len() >= LAYER_WEIGHT_FRAMES || self.layer_tries >= LAYER_WEIGHT_PATIENCE
    }

    /// Learn where the gel lies in its layer's family from a resolved frame
    /// of a size that shows it ([`super::layer_weight`]), and take the
    /// median weight so far once there are [`LAYER_WEIGHT_MIN`]: the fits'
    /// field and the tie's drift follow it (docs/sensing.md, "On a layer").
    fn learn_layer(&mut self, frame: &SensorFrame, m: &Measurement, cfg: &SensingConfig) {
        let Some(family) = self.cfg.layer.as_ref().and_then(|l| l.family.clone()) else {
            return;
        };
        self.layer_tries += 1;
        let (lo, hi) = LAYER_WEIGHT_RADII_MM;
        if !(lo..=hi).contains(&m.contact_radius_mm) || m.gamma1_mm.is_nan() || m.gamma1_mm <= 0.0 {
            return;
        }
        let Some(s) = super::layer_weight(frame, m.contact_centre_mm, m.gamma1_mm, m.contact_radius_mm, &family, cfg)
        else {
            return;
        };
        self.layer_weights.push(s);
        if self.layer_weights.len() >= LAYER_WEIGHT_MIN {
            let mut w = self.layer_weights.clone();
            let Some(median) = quantile(&mut w, 0.5) else { return };
            if let Some(surface) = super::LayerSurface::in_family(family, median) {
                self.learner.set_drift(Some(surface.drift));
                self.near = None;
                self.cfg.layer = Some(surface);
            }
        }
    }

    /// The layer weight the run has learnt, when it learns one (0 and 1:
    /// the two gels of the layer's family, [`super::layer::FAMILY_NU1`]).
    pub fn layer_weight(&self) -> Option<f64> {
        let mut w = self.layer_weights.clone();
        (w.len() >= LAYER_WEIGHT_MIN).then(|| quantile(&mut w, 0.5)).flatten()
    }

    /// [`FrameEstimator::curvature`], computed again only when the radius
    /// moved to another bin or enough estimates came in since.
    fn current_curvature(&mut self) -> Option<(f64, f64)> {
        if self.cfg.contact_curvature_per_mm.is_some() {
            return self.cfg.contact_curvature_per_mm;
        }
        let Some(r) = self.last_radius_mm else {
            return self.learner.estimate();
        };
        let (bin, binned) = ((r / BIN_MM).floor() as i64, self.learner.binned);
        match self.near {
            // (Not a cached "none": the frame that taught the first curvature
            // is the last one of its size the cache saw.)
            Some(n) if n.bin == bin && binned < n.binned + NEAR_STALE && n.curvature.is_some() => n.curvature,
            _ => {
                let curvature = self.learner.estimate_near(r);
                self.near = Some(NearCurvature { bin, binned, curvature });
                curvature
            }
        }
    }

    /// The marker noise pooled over the recent frames (normal, tangential),
    /// mm, once enough degrees of freedom are in (unless the configuration
    /// fixes it).
    pub fn marker_noise(&self) -> Option<(f64, f64)> {
        self.cfg.marker_noise_mm.or_else(|| Some((self.normal_noise.sd()?, self.tangential_noise.sd()?)))
    }

    /// The curvature small contacts are fitted with now, if any: learnt at
    /// about the last contact's size when the run has resolved contacts of
    /// that size, else at the smallest ones it resolved.
    pub fn curvature(&self) -> Option<(f64, f64)> {
        self.cfg.contact_curvature_per_mm.or_else(|| match self.last_radius_mm {
            Some(r) => self.learner.estimate_near(r),
            None => self.learner.estimate(),
        })
    }

    /// Whether this run's frames have shown the gel tacky (every small
    /// contact at the known centre is then read with the punch term).
    pub fn is_tacky(&self) -> bool {
        self.tacky
    }

    /// Where small contacts are fitted now, if known.
    pub fn centre(&self) -> Option<[f64; 2]> {
        self.cfg.contact_centre_mm.or_else(|| self.learner.centre())
    }

    /// Measure one frame, and learn from it when it resolves its contact.
    pub fn measure(&mut self, frame: &SensorFrame) -> Result<Measurement, SensingError> {
        let settled = self.layer_settled();
        if settled && !self.unprobed.is_empty() && self.current_curvature().is_some() && self.centre().is_some() {
            let cfg = SensingConfig {
                contact_curvature_per_mm: self.current_curvature(),
                contact_centre_mm: self.centre(),
                marker_noise_mm: self.marker_noise(),
                adhesive: false,
                probe_adhesion: true,
                ..self.cfg.clone()
            };
            self.probe_kept(&cfg);
        }
        let mut cfg = SensingConfig {
            contact_curvature_per_mm: self.current_curvature(),
            contact_centre_mm: self.centre(),
            marker_noise_mm: self.marker_noise(),
            adhesive: self.cfg.adhesive || self.tacky,
            probe_adhesion: settled && !self.tacky && self.probes < MAX_PROBES,
            ..self.cfg.clone()
        };
        let mut m = match measure(frame, &cfg) {
            Ok(m) => m,
            Err(e) => {
                self.last_radius_mm = None;
                return Err(e);
            }
        };
        // The first frame after a move is read with the curvature learnt at
        // the last contact's size; when its own contact is of another size,
        // it is read again with the curvature learnt at that one.
        let resized = self.last_radius_mm.is_some_and(|r| (m.contact_radius_mm / r).ln().abs() > RESIZED);
        if resized && self.cfg.contact_curvature_per_mm.is_none() && cfg.contact_curvature_per_mm.is_some() {
            self.last_radius_mm = Some(m.contact_radius_mm);
            let again = SensingConfig { contact_curvature_per_mm: self.current_curvature(), ..cfg.clone() };
            if again.contact_curvature_per_mm != cfg.contact_curvature_per_mm
                && let Ok(m_again) = measure(frame, &again)
            {
                (m, cfg) = (m_again, again);
            }
        }
        self.last_radius_mm = Some(m.contact_radius_mm);
        // A frame the probe could not read yet (no curvature, or a layer's
        // field not learnt) is kept for it rather than counted as showing no
        // adhesion.
        let want_probe = !self.tacky && self.probes < MAX_PROBES;
        let unread =
            want_probe && (!settled || cfg.contact_curvature_per_mm.is_none() || cfg.contact_centre_mm.is_none());
        if unread {
            if self.unprobed.len() == ADHESIVE_WINDOW {
                self.unprobed.pop_front();
            }
            self.unprobed.push_back(frame.clone());
        } else {
            self.weigh_adhesion(m.adhesive);
            if cfg.probe_adhesion {
                self.probes += 1;
            }
        }
        self.normal_noise.add(m.depth_noise_mm, m.depth_dof);
        self.tangential_noise.add(m.rotation_noise_mm, m.rotation_dof);
        if !settled {
            self.learn_layer(frame, &m, &cfg);
        }
        if let Some((c, sd)) = m.contact_curvature_per_mm {
            self.learner.add(m.contact_radius_mm, c, sd, m.contact_centre_mm);
        }
        Ok(m)
    }
}

/// Frames whose residuals are pooled into the marker noise (the latest).
const NOISE_FRAMES: usize = 300;

/// Degrees of freedom before the pooled noise is used (a 5 % error).
const NOISE_MIN_DOF: usize = 200;

/// The marker noise from many frames' fit residuals: each frame's variance
/// weighted by its degrees of freedom, over the latest [`NOISE_FRAMES`].
#[derive(Debug, Clone, Default, PartialEq)]
struct NoisePool {
    frames: std::collections::VecDeque<(f64, usize)>,
}

impl NoisePool {
    fn add(&mut self, sd_mm: f64, dof: usize) {
        if sd_mm.is_finite() && sd_mm > 0.0 && dof > 0 {
            if self.frames.len() == NOISE_FRAMES {
                self.frames.pop_front();
            }
            self.frames.push_back((sd_mm * sd_mm, dof));
        }
    }

    fn sd(&self) -> Option<f64> {
        let dof: usize = self.frames.iter().map(|f| f.1).sum();
        (dof >= NOISE_MIN_DOF).then(|| (self.frames.iter().map(|f| f.0 * f.1 as f64).sum::<f64>() / dof as f64).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_learner_averages_the_smallest_contacts_and_leaves_out_strays() {
        let mut l = CurvatureLearner::default();
        let jitter = [-0.002, 0.001, 0.0, 0.002, -0.001, 0.001];
        for (k, j) in jitter.iter().enumerate().take(4) {
            l.add(1.6 + 0.02 * k as f64, 0.18 + j, 0.002, [0.1 + j, -0.2]);
        }
        assert_eq!((l.estimate(), l.centre()), (None, None));
        l.add(1.7, 0.18 + jitter[4], 0.002, [0.1 + jitter[4], -0.2]);
        // A contact three times larger is beyond the span; a frame that only
        // looked resolved (another centre, another curvature) is a stray.
        l.add(4.8, 0.30, 0.001, [5.0, 5.0]);
        l.add(1.62, 0.25, 0.002, [-0.3, 0.2]);
        let (c, sd) = l.estimate().unwrap();
        let centre = l.centre().unwrap();
        assert!((c - 0.18).abs() < 1e-9 && (sd - 0.002 / 5f64.sqrt()).abs() < 1e-12, "{c} {sd}");
        assert!((centre[0] - 0.1).abs() < 1e-9 && (centre[1] + 0.2).abs() < 1e-12, "{centre:?}");
        // Estimates further apart than their errors widen the error.
        l.add(1.65, 0.19, 0.0005, [0.1, -0.2]);
        let (_, sd2) = l.estimate().unwrap();
        assert!(sd2 > 2.0 * 0.0005 / 6f64.sqrt(), "{sd2}");
        // Non-physical input is ignored.
        let before = l.estimates.len();
        l.add(f64::NAN, 0.2, 0.01, [0.0, 0.0]);
        l.add(1.6, -0.2, 0.01, [0.0, 0.0]);
        l.add(1.6, 0.2, 0.01, [f64::NAN, 0.0]);
        assert_eq!(l.estimates.len(), before);
    }

    #[test]
    fn a_contact_takes_the_curvature_learnt_at_its_own_size() {
        // A curvature that falls with the radius, as in a contact at large
        // strain: 0.176 per mm at 1 mm, 0.002 less per mm of radius.
        let truth = |r: f64| 0.176 - 0.002 * (r - 1.0);
        let jitter = [-0.004, 0.002, 0.0, 0.003, -0.002, 0.001];
        let mut l = CurvatureLearner::default();
        for k in 0..150 {
            let r = 1.0 + 1.5 * k as f64 / 150.0;
            l.add(r, truth(r) * (1.0 + jitter[k % 6]), 0.004, [0.0, 0.0]);
        }
        // Inside the resolved sizes: the line through the estimates near it.
        for r in [1.3, 1.8, 2.2] {
            let (c, sd) = l.estimate_near(r).unwrap();
            assert!((c - truth(r)).abs() < 3.0 * sd + 1e-5, "r {r}: {c} vs {} (sd {sd})", truth(r));
        }
        // The smallest contacts' average is the curvature around 1.0-1.5 mm:
        // at 2.2 mm it would be off by twice the local error.
        let (global, _) = l.estimate().unwrap();
        let (at_22, sd_22) = l.estimate_near(2.2).unwrap();
        assert!((global - at_22).abs() > 2.0 * sd_22, "{global} {at_22} {sd_22}");
        // Below every resolved size, the value at the edge: never extrapolated.
        let (edge, _) = l.estimate_near(1.05).unwrap();
        assert_eq!(l.estimate_near(0.3).unwrap().0, edge);
        // Too few estimates near a size: the smallest contacts' value.
        let mut few = CurvatureLearner::default();
        for k in 0..10 {
            few.add(1.6 + 0.01 * k as f64, 0.18 + 0.001 * jitter[k % 6], 0.004, [0.0, 0.0]);
        }
        assert_eq!(few.estimate_near(1.65), few.estimate());
    }

    /// The torsion sweep holds a deep contact for hundreds of resolved
    /// frames; a contact that shrinks back after it, with too few resolved
    /// sizes below it for a line, takes the curvature of the sizes near it,
    /// not that of the hold, which those frames have made the lower fifth of
    /// every estimate. (A few small, noisy frames below the window are what
    /// leave the line one-sided, as on the emulated rig.)
    #[test]
    fn a_long_hold_of_deep_frames_does_not_stand_for_a_smaller_contact() {
        let mut l = CurvatureLearner::default();
        for c in [0.138, 0.143, 0.133, 0.120] {
            l.add(1.19, c, 0.01, [0.0, 0.0]);
        }
        for k in 0..40 {
            l.add(1.8 + 0.8 * k as f64 / 40.0, 0.125, 0.002, [0.0, 0.0]);
        }
        for _ in 0..360 {
            l.add(4.47, 0.142, 0.0005, [0.0, 0.0]);
        }
        let (c, sd) = l.estimate_near(1.6).expect("a curvature");
        assert!((c - 0.125).abs() < 0.002, "at 1.6 mm: {c} ± {sd}");
        // The hold's own size still takes its own curvature.
        assert!((l.estimate_near(4.47).expect("a curvature").0 - 0.142).abs() < 1e-3);
    }

    /// On a declared layer a curvature learnt on resolved contacts is
    /// carried to a smaller contact by the layer's drift (gamma1 / a² rises
    /// as the contact shrinks against the gel's thickness), with the drift's
    /// own uncertainty; within the resolved sizes nothing changes.
    #[test]
    fn on_a_layer_a_small_contact_takes_the_curvature_carried_to_its_size() {
        let drift = TieDrift::declared(sim::physics::Layer::bonded(5.0), sim::physics::Body::new(1.1, 0.39, 5.0))
            .expect("the layer model");
        let (mut flat, mut layer) = (CurvatureLearner::default(), CurvatureLearner::with_drift(Some(drift)));
        for k in 0..150 {
            let r = 1.6 + 1.0 * k as f64 / 150.0;
            for l in [&mut flat, &mut layer] {
                l.add(r, 0.13 * drift.ratio(1.6, r), 0.002, [0.0, 0.0]);
            }
        }
        let (c_flat, sd_flat) = flat.estimate_near(0.5).unwrap();
        let (c_layer, sd_layer) = layer.estimate_near(0.5).unwrap();
        let truth = 0.13 * drift.ratio(1.6, 0.5);
        println!(
            "at 0.5 mm: half-space tie {c_flat:.4} ± {sd_flat:.4}, layer {c_layer:.4} ± {sd_layer:.4}, truth {truth:.4}"
        );
        assert!((c_layer / truth - 1.0).abs() < 0.01, "{c_layer} vs {truth}");
        assert!(c_flat < 0.92 * truth, "the half-space tie would take {c_flat} for {truth}");
        assert!(sd_layer > 0.1 * DRIFT_SD_FRACTION * (truth - 0.13), "{sd_layer}");
        let (inside, inside_layer) = (flat.estimate_near(2.0).unwrap(), layer.estimate_near(2.0).unwrap());
        assert_eq!(inside, inside_layer);
    }

    #[test]
    fn the_marker_noise_is_pooled_by_degrees_of_freedom() {
        let mut p = NoisePool::default();
        // 20 frames of 8 degrees of freedom are not enough to trust.
        for _ in 0..20 {
            p.add(0.004, 8);
        }
        assert_eq!(p.sd(), None);
        // Variances weighted by their degrees of freedom: (100 * 16 + 100 * 36) / 200.
        let mut p = NoisePool::default();
        for _ in 0..10 {
            p.add(0.004, 10);
            p.add(0.006, 10);
        }
        assert!((p.sd().unwrap() - 26e-6f64.sqrt()).abs() < 1e-12, "{:?}", p.sd());
        // Nothing non-physical gets in; only the latest frames count.
        p.add(f64::NAN, 10);
        p.add(0.004, 0);
        assert_eq!(p.frames.len(), 20);
        for _ in 0..NOISE_FRAMES {
            p.add(0.003, 10);
        }
        assert!((p.sd().unwrap() - 0.003).abs() < 1e-12);
    }
}
