//! The "true rig": commanded stage / mount history in, the readings a rig with
//! the profile's effects gives out. The synthetic generator, the simulated rig
//! and the diagnosis's refits all use this one model, so what diagnosis fits is
//! exactly what the simulator produces.
//!
//! Order of the chain for one reading at rig time t:
//! stage command -> stage play (backlash) -> minus contact offset, plus the
//! frame's thermal drift -> contact solve (layer, adhesion, frame compliance,
//! or the viscoelastic history) -> sensor gain on gamma1; mount command ->
//! mount play -> torsion split (layer, rod correction at the contact's own
//! radius, partial slip).

use std::f64::consts::PI;
use std::sync::Arc;

use crate::physics::torsion::eq35_contact_radius_mm;
use crate::physics::{ContactPair, NormalModel, YOFFE};

use super::law::{self, ContactLaw, LawState};
use super::partial_slip::SlipState;
use super::stage_backlash::Play;
use super::{EffectError, SimProfile, bracketed_root, finite_thickness};

/// Where the rig was told to be at one instant: the commanded stage and mount
/// (before any play or offset), the input of [`TrueRig::read`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommandedPose {
    /// Rig time, s.
    pub t_s: f64,
    /// Commanded stage approach, mm.
    pub stage_mm: f64,
    /// Commanded mount angle, degrees.
    pub rot_deg: f64,
}

/// What the sensor reads (noise-free) plus the true contact state behind it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Reading {
    /// Depth as the sensor reports it (0 without contact), mm.
    pub gamma1_mm: f64,
    /// Rotation of the contact region as the sensor reports it, degrees.
    pub theta1_deg: f64,
    /// True elastomer displacement, mm.
    pub gamma1_true_mm: f64,
    /// True indenter deformation, mm.
    pub gamma2_mm: f64,
    pub force_n: f64,
    pub contact_radius_mm: f64,
    pub in_contact: bool,
    /// The flat-punch (adhesion) part of `gamma1_mm` as the sensor reports it,
    /// mm (<= 0; 0 without adhesion): the marker field is Hertz's for the
    /// rest of the depth plus a punch's (sim::sensor::field::punch_shape).
    pub gamma1_punch_mm: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Contact {
    gamma1: f64,
    gamma2: f64,
    force: f64,
    a: f64,
    delta: f64,
    /// The elastomer's share of the punch displacement, mm.
    punch1: f64,
}

impl Contact {
    /// A contact without adhesion from its clean state, at approach `delta` (mm).
    fn clean(st: LawState, delta: f64) -> Self {
        Self {
            gamma1: st.gamma1_mm,
            gamma2: st.gamma2_mm,
            force: st.force_n,
            a: st.contact_radius_mm,
            delta,
            punch1: 0.0,
        }
    }
}

/// How the punch (adhesion) term is set at a given contact radius.
#[derive(Clone, Copy)]
enum Punch {
    None,
    /// Edge in equilibrium with energy release rate G (N/mm).
    Edge(f64),
    /// Edge pinned: the punch displacement takes whatever the stage asks.
    Pinned(f64),
}

/// Largest contact radius the solver looks at, in indenter radii.
const MAX_RADIUS_R2: f64 = 4.0;

/// A rig with effects, advanced one reading at a time (readings must come in time order).
#[derive(Debug, Clone)]
pub struct TrueRig {
    pair: ContactPair,
    profile: SimProfile,
    clean: NormalModel,
    e1s: f64,
    e2s: f64,
    r_star: f64,
    b1: f64,
    b2: f64,
    /// Shear moduli G1, G2 of elastomer and indenter, MPa (Eq. 33).
    shear1_mpa: f64,
    shear2_mpa: f64,
    stage_play: Option<Play>,
    rot_play: Option<Play>,
    /// Contact radius held by the adhesive edge (0: no contact).
    edge_a: f64,
    // Viscoelastic history.
    q: f64,
    f_prev: f64,
    t_prev: Option<f64>,
    /// Approach of the last reading (stage after play and offset, plus drift).
    last_s: Option<f64>,
    /// Stage after play and offset of the last reading (a slip state lives
    /// while the stage stands; the drift moves the contact under it).
    last_stage: Option<f64>,
    last: Contact,
    slip: Option<(f64, SlipState)>,
    /// Viscoelastic torsion history: filtered torque, last torque, last time.
    tq: f64,
    m_prev: f64,
    tors_t: Option<f64>,
    torsion_cache: Option<(f64, f64, f64, f64, f64)>,
    /// A contact solved elsewhere (the declared layer), which then replaces
    /// the paper's contact; with the platform approach of its last state.
    law: Option<Arc<dyn ContactLaw>>,
    law_delta: f64,
}

impl TrueRig {
    pub fn new(pair: ContactPair, profile: &SimProfile) -> Result<Self, EffectError> {
        profile.validate()?;
        let pair = profile.true_pair(pair);
        let clean = NormalModel::new(pair)?;
        Ok(Self {
            pair,
            profile: profile.clone(),
            clean,
            e1s: pair.elastomer.plane_strain_mpa(),
            e2s: pair.indenter.plane_strain_mpa(),
            r_star: pair.composite_radius_mm(),
            b1: pair.elastomer.tatara_mm_per_n(),
            b2: pair.indenter.tatara_mm_per_n(),
            shear1_mpa: pair.elastomer.shear_mpa(),
            shear2_mpa: pair.indenter.shear_mpa(),
            stage_play: profile.stage_backlash.map(|p| Play::new(p.b_mm, p.engaged)),
            rot_play: profile.rotation_backlash.map(|p| Play::new(p.b_deg, p.engaged)),
            edge_a: 0.0,
            q: profile.viscoelastic.map_or(0.0, |v| v.memory_n),
            f_prev: 0.0,
            t_prev: None,
            last_s: None,
            last_stage: None,
            last: Contact::default(),
            slip: None,
            tq: 0.0,
            m_prev: 0.0,
            tors_t: None,
            torsion_cache: None,
            law: None,
            law_delta: 0.0,
        })
    }

    /// A rig whose clean contact is `law` (docs/physics.md, "Rig effects on a
    /// declared layer"): the profile's rig-level effects wrap it; an effect
    /// that changes the contact itself is refused (`EffectError::NotOnLayer`).
    pub fn on_law(pair: ContactPair, profile: &SimProfile, law: Arc<dyn ContactLaw>) -> Result<Self, EffectError> {
        law::check(profile)?;
        let mut rig = Self::new(pair, profile)?;
        rig.law = Some(law);
        Ok(rig)
    }

    /// The contact pair the rig uses (the profile's `material` applied).
    pub fn pair(&self) -> &ContactPair {
        &self.pair
    }

    /// The effects this rig has.
    pub fn profile(&self) -> &SimProfile {
        &self.profile
    }

    fn frame_c(&self) -> f64 {
        self.profile.frame_compliance.map_or(0.0, |p| p.c_mm_per_n)
    }

    /// Every quantity at contact radius `a` (elastic: layer, adhesion, frame).
    fn contact_at(&self, a: f64, punch: Punch) -> Contact {
        let (phi, nu1) = (self.profile.finite_thickness.map(|p| p.h_mm), self.pair.elastomer.nu);
        let phi = phi.map_or(1.0, |h| finite_thickness::phi(a / h, nu1));
        let e1e = self.e1s * phi;
        let b1e = self.b1 / phi;
        let es = 1.0 / (1.0 / e1e + 1.0 / self.e2s);
        let hz = a * a / self.r_star;
        let c = self.frame_c();
        let k_h = 4.0 * es * a * a * a / (3.0 * self.r_star);
        let dp = match punch {
            Punch::None => 0.0,
            Punch::Edge(g) => super::adhesion::punch_displacement(g, a, es),
            Punch::Pinned(stage) => {
                let d0 = es / e1e * hz + es / self.e2s * YOFFE * hz + (c - b1e - self.b2) * k_h;
                (stage - d0) / (1.0 + 2.0 * es * a * (c - b1e - self.b2))
            }
        };
        let force = k_h + 2.0 * es * a * dp;
        let gamma1 = es / e1e * (hz + dp) - b1e * force;
        let gamma2 = es / self.e2s * (YOFFE * hz + dp) - self.b2 * force;
        Contact { gamma1, gamma2, force, a, delta: gamma1 + gamma2 + c * force, punch1: es / e1e * dp }
    }

    fn es_at(&self, a: f64) -> f64 {
        let phi =
            self.profile.finite_thickness.map_or(1.0, |p| finite_thickness::phi(a / p.h_mm, self.pair.elastomer.nu));
        1.0 / (1.0 / (self.e1s * phi) + 1.0 / self.e2s)
    }

    /// Root of delta(a) = s for a >= lo on a rising branch, f(lo) < 0 assumed.
    fn solve_rising(&self, s: f64, punch: Punch, lo: f64, guess: f64) -> Result<Contact, EffectError> {
        let f = |a: f64| self.contact_at(a, punch).delta - s;
        let amax = MAX_RADIUS_R2 * self.pair.indenter.r_mm;
        let flo = f(lo);
        if flo >= 0.0 {
            return Ok(self.contact_at(lo, punch));
        }
        // Warm bracket around the guess, widened until it holds the root.
        let (mut a_lo, mut f_lo) = (lo, flo);
        let mut hi = guess.max(lo * 1.01 + 1e-9).max(1e-6);
        let mut fhi = f(hi);
        while fhi < 0.0 {
            a_lo = hi;
            f_lo = fhi;
            hi *= 1.5;
            if hi > amax {
                return Err(EffectError::NoSolution {
                    stage_mm: s,
                    why: "contact radius beyond the model's range".into(),
                });
            }
            fhi = f(hi);
        }
        if guess > a_lo && guess < hi {
            let fg = f(guess * 0.999);
            if fg < 0.0 {
                a_lo = guess * 0.999;
                f_lo = fg;
            }
        }
        let a = bracketed_root(f, a_lo, hi, f_lo, fhi, 1e-13 * hi.max(1e-3));
        Ok(self.contact_at(a, punch))
    }

    /// Elastic contact at true approach `s` (adhesion history in `edge_a`).
    fn solve_elastic(&mut self, s: f64) -> Result<Contact, EffectError> {
        let guess = if self.last.a > 0.0 { self.last.a } else { (s.max(0.0) / self.clean_p()).sqrt() };
        let Some(adh) = self.profile.adhesion else {
            if s <= 0.0 {
                return Ok(Contact::default());
            }
            if self.profile.finite_thickness.is_none() && self.profile.frame_compliance.is_none() {
                // The contact itself is the paper's: use its own solver, so a rig
                // whose effects all act outside the contact reads the clean model exactly.
                let st =
                    self.clean.solve(s).map_err(|e| EffectError::NoSolution { stage_mm: s, why: e.to_string() })?;
                return Ok(Contact::clean(st.into(), s));
            }
            return self.solve_rising(s, Punch::None, 0.0, guess);
        };
        let w = adh.w_n_per_mm();
        let wr = w * adh.eta;
        let tiny = 1e-9;
        if self.edge_a <= 0.0 {
            if s < 0.0 {
                return Ok(Contact::default());
            }
            let c = self.solve_rising(s, Punch::Edge(w), tiny, guess.max(1e-4))?;
            self.edge_a = c.a;
            return Ok(c);
        }
        let a0 = self.edge_a;
        let pinned = self.contact_at(a0, Punch::Pinned(s));
        let es = self.es_at(a0);
        let dp_pin = {
            let c0 = self.contact_at(a0, Punch::None);
            let k = 2.0 * es * a0;
            // gamma terms are linear in dp: recover it from the force.
            (pinned.force - c0.force) / k
        };
        let g_pin = es * dp_pin * dp_pin / (2.0 * PI * a0);
        if dp_pin > 0.0 || g_pin < w {
            let c = self.solve_rising(s, Punch::Edge(w), a0, a0 * 1.01)?;
            self.edge_a = c.a;
            return Ok(c);
        }
        if g_pin <= wr {
            return Ok(pinned);
        }
        // Receding: find the stable branch's minimum below a0, then the root on it.
        let d = |a: f64| self.contact_at(a, Punch::Edge(wr)).delta;
        let (mut lo, mut hi) = (tiny, a0);
        let gr = 0.5 * (5f64.sqrt() - 1.0);
        let (mut x1, mut x2) = (hi - gr * (hi - lo), lo + gr * (hi - lo));
        let (mut d1, mut d2) = (d(x1), d(x2));
        for _ in 0..60 {
            if d1 < d2 {
                hi = x2;
                x2 = x1;
                d2 = d1;
                x1 = hi - gr * (hi - lo);
                d1 = d(x1);
            } else {
                lo = x1;
                x1 = x2;
                d1 = d2;
                x2 = lo + gr * (hi - lo);
                d2 = d(x2);
            }
        }
        let a_min = 0.5 * (lo + hi);
        if d(a_min) > s {
            // Pull-off: the contact snaps free.
            self.edge_a = 0.0;
            return Ok(Contact::default());
        }
        let c = self.solve_rising(s, Punch::Edge(wr), a_min, a0)?;
        self.edge_a = c.a;
        Ok(c)
    }

    fn clean_p(&self) -> f64 {
        let es = self.pair.composite_modulus_mpa();
        (es / self.e1s + YOFFE * es / self.e2s) / self.r_star
    }

    /// Lee-Radok viscoelastic contact at true approach `s`, advancing the history to `t`.
    fn solve_visco(&mut self, s: f64, t: f64) -> Result<Contact, EffectError> {
        let Some(v) = self.profile.viscoelastic else {
            return Err(EffectError::Unsupported("viscoelastic"));
        };
        let j_inf = 1.0 / self.e1s;
        let j0 = j_inf / v.rho;
        let j2 = 1.0 / self.e2s;
        let c = self.frame_c();
        let span = match self.t_prev {
            Some(tp) => (t - tp).max(0.0),
            None => super::viscoelastic::MAX_STEP_S,
        };
        self.t_prev = Some(t);
        let n = super::viscoelastic::substeps(span);
        let dt = (span / n as f64).max(1e-9);
        let e = (-dt / v.tau_s).exp();
        let w = (1.0 - e) / (dt / v.tau_s);
        let (r_star, b1, b2) = (self.r_star, self.b1, self.b2);
        let mut out = Contact::default();
        for _ in 0..n {
            let (q, fp) = (self.q, self.f_prev);
            let state = |f: f64| {
                let qn = e * q + w * (f - fp);
                let h = j_inf * f - (j_inf - j0) * qn;
                let a = (0.75 * r_star * (h + j2 * f)).max(0.0).cbrt();
                let load = if a > 0.0 { 0.75 * f / a } else { 0.0 };
                let g2 = j2 * YOFFE * load - b2 * f;
                let g1 = a * a / r_star - j2 * load - b1 / j_inf * h;
                (Contact { gamma1: g1, gamma2: g2, force: f, a, delta: g1 + g2 + c * f, punch1: 0.0 }, qn)
            };
            let (c0, q0) = state(0.0);
            let (contact, qn) = if s <= c0.delta {
                (Contact::default(), q0)
            } else {
                let fz = |f: f64| state(f).0.delta - s;
                let mut hi = (fp * 1.2).max(0.05);
                let mut fhi = fz(hi);
                let mut lo = 0.0;
                let mut flo = c0.delta - s;
                while fhi < 0.0 {
                    lo = hi;
                    flo = fhi;
                    hi *= 2.0;
                    if hi > 1e6 {
                        return Err(EffectError::NoSolution { stage_mm: s, why: "no force matches the stage".into() });
                    }
                    fhi = fz(hi);
                }
                let f = bracketed_root(fz, lo, hi, flo, fhi, 1e-13 * hi);
                state(f)
            };
            self.q = qn;
            self.f_prev = contact.force;
            out = contact;
        }
        Ok(out)
    }

    /// Torsion compliances at the current contact: (C1, C2, C_rod) in rad per N mm, and a_t.
    fn torsion_compliances(&mut self, c: &Contact) -> Result<(f64, f64, f64, f64), EffectError> {
        if let Some((g2, c1, c2, crod, at)) = self.torsion_cache {
            if g2 == c.gamma2 {
                return Ok((c1, c2, crod, at));
            }
        }
        let r2 = self.pair.indenter.r_mm;
        let beta = c.gamma2 / r2;
        let a35 = eq35_contact_radius_mm(r2, beta);
        let a_clean = self
            .clean
            .solve_for_gamma2(c.gamma2)
            .map_err(|e| EffectError::NoSolution { stage_mm: c.delta, why: e.to_string() })?
            .contact_radius_mm;
        let a_t = if a_clean > 0.0 && c.a > 0.0 { a35 * c.a / a_clean } else { a35 };
        let layer = self.profile.finite_thickness.map_or(1.0, |p| finite_thickness::torsion_factor(c.a / p.h_mm));
        let c1 = 3.0 / (16.0 * self.shear1_mpa * a_t.powi(3) * layer);
        let c2 = 3.0 / (16.0 * self.shear2_mpa * a_t.powi(3));
        let crod = 2.0 * r2 * (1.0 - beta) / (PI * self.shear2_mpa * r2.powi(4));
        self.torsion_cache = Some((c.gamma2, c1, c2, crod, a_t));
        Ok((c1, c2, crod, a_t))
    }

    /// Torsion of a standard-linear-solid elastomer at mount angle `total` (rad),
    /// held since the last reading: the elastomer's compliance creeps from
    /// c1/rho to its relaxed c1 (same kernel as the normal contact, on the
    /// torque history), in series with the elastic indenter and rod `c_series`.
    /// Exact exponential recursion per sub-step; the torque relaxes during a hold.
    fn visco_theta1(&mut self, total: f64, c1: f64, c_series: f64, t: f64) -> f64 {
        let Some(v) = self.profile.viscoelastic else {
            return total * c1 / (c1 + c_series);
        };
        let k = 1.0 - 1.0 / v.rho;
        let span = self.tors_t.map_or(0.0, |tp| (t - tp).max(0.0));
        self.tors_t = Some(t);
        let n = super::viscoelastic::substeps(span);
        let dt = span / n as f64;
        let (e, w) =
            if dt > 0.0 { ((-dt / v.tau_s).exp(), (1.0 - (-dt / v.tau_s).exp()) / (dt / v.tau_s)) } else { (1.0, 1.0) };
        let mut m = self.m_prev;
        for _ in 0..n {
            // total = c1 (M - k (e q + w (M - M_prev))) + c_series M, solved for M.
            m = (total + c1 * k * (e * self.tq - w * self.m_prev)) / (c1 * (1.0 - k * w) + c_series);
            self.tq = e * self.tq + w * (m - self.m_prev);
            self.m_prev = m;
        }
        total - c_series * m
    }

    /// The reading at rig time `t_s` for the commanded stage and mount angle.
    pub fn read(&mut self, cmd: CommandedPose) -> Result<Reading, EffectError> {
        let stage = match self.stage_play.as_mut() {
            Some(p) => p.step(cmd.stage_mm),
            None => cmd.stage_mm,
        };
        let stage = stage - self.profile.contact_offset.map_or(0.0, |p| p.contact_offset_mm);
        // The frame's thermal expansion moves the indenter toward the gel
        // (docs/physics.md 2.9): the approach itself drifts, and the contact
        // with it, so the sensor sees a real contact of that approach.
        let s = stage + self.profile.thermal_drift.map_or(0.0, |p| p.offset_mm(cmd.t_s));
        if let Some(law) = self.law.clone() {
            return self.read_on_law(law.as_ref(), s, cmd);
        }
        let history = self.profile.adhesion.is_some() || self.profile.viscoelastic.is_some();
        let approach_changed = self.last_s != Some(s);
        let stage_changed = self.last_stage != Some(stage);
        let contact = if self.profile.viscoelastic.is_some() {
            self.solve_visco(s, cmd.t_s)?
        } else if !history && !approach_changed {
            self.last
        } else {
            self.solve_elastic(s)?
        };
        if stage_changed {
            self.slip = None;
        }
        self.last_s = Some(s);
        self.last_stage = Some(stage);
        self.last = contact;
        let in_contact = contact.a > 0.0;
        let gain = self.profile.sensor_gain.map_or(1.0, |p| p.g);
        let gamma1_read = if in_contact { gain * contact.gamma1 } else { 0.0 };

        let rot = match self.rot_play.as_mut() {
            Some(p) => p.step(cmd.rot_deg),
            None => cmd.rot_deg,
        };
        let total = rot.to_radians();
        let creeping = self.profile.viscoelastic.is_some() && self.profile.partial_slip.is_none();
        if !in_contact {
            (self.tq, self.m_prev, self.tors_t) = (0.0, 0.0, None);
        }
        let theta1 = if !in_contact || (total == 0.0 && self.slip.is_none() && (!creeping || self.tq == 0.0)) {
            if creeping && in_contact {
                self.tors_t = Some(cmd.t_s);
            }
            0.0
        } else {
            let (c1, c2, crod, a_t) = self.torsion_compliances(&contact)?;
            match self.profile.partial_slip {
                None if creeping => self.visco_theta1(total, c1, c2 + crod, cmd.t_s),
                None => total * c1 / (c1 + c2 + crod),
                Some(ps) => {
                    if self.slip.is_none() {
                        self.slip = Some((s, SlipState::new(ps.mu, contact.force, a_t, c1, c2, crod)));
                    }
                    let slip = self.slip.as_mut().map(|(_, st)| st);
                    slip.and_then(|st| st.theta1(total)).ok_or(EffectError::GrossSlip { rot_deg: cmd.rot_deg })?
                }
            }
        };
        Ok(Reading {
            gamma1_mm: gamma1_read,
            theta1_deg: theta1.to_degrees(),
            gamma1_true_mm: contact.gamma1,
            gamma2_mm: contact.gamma2,
            force_n: contact.force,
            contact_radius_mm: contact.a,
            in_contact,
            gamma1_punch_mm: if in_contact { gain * contact.punch1 } else { 0.0 },
        })
    }
}

impl TrueRig {
    /// [`TrueRig::read`] on a contact law, from the approach `s` (the stage
    /// after its play, zero and drift): the frame gives by its compliance times
    /// the force, so the platform's approach d solves d + c F(d) = s; the mount's
    /// play, then the law's twist; the sensor's gain on gamma1.
    fn read_on_law(&mut self, law: &dyn ContactLaw, s: f64, cmd: CommandedPose) -> Result<Reading, EffectError> {
        let fail = |why: String| EffectError::NoSolution { stage_mm: s, why };
        if self.last_s != Some(s) {
            let c = self.frame_c();
            let at = |d: f64| law.normal(d).map_err(fail);
            let (d, st) = if s <= 0.0 {
                (s, LawState::default())
            } else if c == 0.0 {
                (s, at(s)?)
            } else {
                // d + c F(d) rises from -s at d = 0 to c F(s) >= 0 at d = s.
                let top = at(s)?;
                let mut err = None;
                let f = |d: f64| match law.normal(d) {
                    Ok(st) => d + c * st.force_n - s,
                    Err(e) => {
                        err = Some(e);
                        f64::NAN
                    }
                };
                let d = if top.force_n <= 0.0 {
                    s
                } else {
                    bracketed_root(f, 0.0, s, -s, c * top.force_n, 1e-12 * s.max(1e-3))
                };
                if let Some(e) = err {
                    return Err(fail(e));
                }
                (d, at(d)?)
            };
            self.last_s = Some(s);
            self.law_delta = d;
            self.last = Contact::clean(st, s);
        }
        let contact = self.last;
        let in_contact = contact.a > 0.0 && self.law_delta > 0.0;
        let gain = self.profile.sensor_gain.map_or(1.0, |p| p.g);
        let rot = match self.rot_play.as_mut() {
            Some(p) => p.step(cmd.rot_deg),
            None => cmd.rot_deg,
        };
        let theta1_deg = if in_contact && rot != 0.0 {
            law.theta1_deg(self.law_delta, rot).map_err(|why| EffectError::NoSolution { stage_mm: s, why })?
        } else {
            0.0
        };
        Ok(Reading {
            gamma1_mm: if in_contact { gain * contact.gamma1 } else { 0.0 },
            theta1_deg,
            gamma1_true_mm: contact.gamma1,
            gamma2_mm: contact.gamma2,
            force_n: contact.force,
            contact_radius_mm: contact.a,
            in_contact,
            gamma1_punch_mm: 0.0,
        })
    }
}

/// Readings for a whole commanded history (time order), from a fresh rig.
pub fn simulate(pair: ContactPair, profile: &SimProfile, cmds: &[CommandedPose]) -> Result<Vec<Reading>, EffectError> {
    let mut rig = TrueRig::new(pair, profile)?;
    cmds.iter().map(|&c| rig.read(c)).collect()
}

/// [`simulate`] on a contact law (the declared layer): [`TrueRig::on_law`].
pub fn simulate_on(
    pair: ContactPair,
    profile: &SimProfile,
    law: Arc<dyn ContactLaw>,
    cmds: &[CommandedPose],
) -> Result<Vec<Reading>, EffectError> {
    let mut rig = TrueRig::on_law(pair, profile, law)?;
    cmds.iter().map(|&c| rig.read(c)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::*;
    use crate::physics::torsion_at;

    fn pair() -> ContactPair {
        crate::defaults::pair()
    }

    fn sweep() -> Vec<CommandedPose> {
        let mut v: Vec<CommandedPose> =
            (0..=60).map(|i| CommandedPose { t_s: i as f64, stage_mm: i as f64 * 0.05, rot_deg: 0.0 }).collect();
        v.extend((0..60).rev().map(|i| CommandedPose {
            t_s: 120.0 - i as f64,
            stage_mm: i as f64 * 0.05,
            rot_deg: 0.0,
        }));
        v
    }

    #[test]
    fn empty_profile_is_the_clean_model() {
        let p = pair();
        let m = NormalModel::new(p).unwrap();
        let r = simulate(p, &SimProfile::default(), &sweep()).unwrap();
        for (c, r) in sweep().iter().zip(&r) {
            let s = m.solve(c.stage_mm).unwrap();
            assert_eq!(r.gamma1_mm, s.gamma1_mm);
        }
        let mut rig = TrueRig::new(p, &SimProfile::default()).unwrap();
        let st = m.solve_for_gamma2(1.0).unwrap();
        let rd = rig.read(CommandedPose { t_s: 0.0, stage_mm: st.delta_mm, rot_deg: 5.0 }).unwrap();
        let expect = torsion_at(&p, 0.2, 5f64.to_radians()).theta1_rad.to_degrees();
        assert!((rd.theta1_deg - expect).abs() < 1e-9, "{} vs {expect}", rd.theta1_deg);
    }

    #[test]
    fn a_huge_time_gap_relaxes_the_creep_in_bounded_steps() {
        // After a hold far longer than tau the standard linear solid is the
        // elastic contact at its relaxed modulus; a gap of 1e12 s gets there in at
        // most MAX_SUBSTEPS steps instead of 5e12.
        assert_eq!(viscoelastic::substeps(1e12), viscoelastic::MAX_SUBSTEPS);
        assert_eq!(viscoelastic::substeps(0.0), 1);
        assert_eq!(viscoelastic::substeps(1.0), 5);
        let p = pair();
        let prof = SimProfile {
            viscoelastic: Some(viscoelastic::Params { rho: 1.5, tau_s: 5.0, memory_n: 0.0 }),
            ..Default::default()
        };
        let mut rig = TrueRig::new(p, &prof).unwrap();
        let s = 1.5;
        let first = rig.read(CommandedPose { t_s: 0.0, stage_mm: s, rot_deg: 0.0 }).unwrap();
        let late = rig.read(CommandedPose { t_s: 1e12, stage_mm: s, rot_deg: 0.0 }).unwrap();
        let relaxed = NormalModel::new(p).unwrap().solve(s).unwrap().gamma1_mm;
        assert!(first.gamma1_mm < relaxed - 1e-3, "{} vs {relaxed}", first.gamma1_mm);
        assert!((late.gamma1_mm / relaxed - 1.0).abs() < 1e-6, "{} vs {relaxed}", late.gamma1_mm);
    }

    #[test]
    fn neutral_parameters_reduce_to_clean() {
        let p = pair();
        let clean = simulate(p, &SimProfile::default(), &sweep()).unwrap();
        let prof = SimProfile {
            viscoelastic: Some(viscoelastic::Params { rho: 1.0, tau_s: 5.0, memory_n: 0.0 }),
            frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.0 }),
            ..Default::default()
        };
        let v = simulate(p, &prof, &sweep()).unwrap();
        for (a, b) in clean.iter().zip(&v) {
            assert!((a.gamma1_mm - b.gamma1_mm).abs() < 1e-9, "{} vs {}", a.gamma1_mm, b.gamma1_mm);
        }
        let prof = SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: 1e3 }), ..Default::default() };
        let v = simulate(p, &prof, &sweep()).unwrap();
        for (a, b) in clean.iter().zip(&v) {
            assert!((a.gamma1_mm - b.gamma1_mm).abs() < 2e-3 * a.gamma1_mm.max(1e-3));
        }
    }

    #[test]
    fn effects_have_their_signatures() {
        let p = pair();
        let clean = simulate(p, &SimProfile::default(), &sweep()).unwrap();
        let run = |prof: SimProfile| simulate(p, &prof, &sweep()).unwrap();
        // Layer: gamma1 below the half-space, more so at depth, load = unload.
        let l =
            run(SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: 5.0 }), ..Default::default() });
        assert!(l[60].gamma1_mm < clean[60].gamma1_mm - 0.05);
        assert!((l[60].gamma1_mm - clean[60].gamma1_mm).abs() > (l[10].gamma1_mm - clean[10].gamma1_mm).abs());
        assert!((l[50].gamma1_mm - l[70].gamma1_mm).abs() < 1e-9);
        // Stage backlash: unload deeper by the play, load untouched.
        let b = run(SimProfile {
            stage_backlash: Some(stage_backlash::Params { b_mm: 0.01, engaged: true }),
            ..Default::default()
        });
        assert_eq!(b[30].gamma1_mm, clean[30].gamma1_mm);
        assert!(b[90].gamma1_mm > clean[90].gamma1_mm + 0.003);
        // Viscoelastic: unload above load at the same stage.
        let v = run(SimProfile {
            viscoelastic: Some(viscoelastic::Params { rho: 1.05, tau_s: 5.0, memory_n: 0.0 }),
            ..Default::default()
        });
        assert!(v[90].gamma1_mm > v[30].gamma1_mm + 0.003, "{} {}", v[90].gamma1_mm, v[30].gamma1_mm);
        // Adhesion: contact still held (negative depth) back at stage 0.
        let a = run(SimProfile { adhesion: Some(adhesion::Params { w_mj_m2: 80.0, eta: 3.0 }), ..Default::default() });
        assert!(a[120].in_contact && a[120].gamma1_mm < 0.0, "{:?}", a[120]);
        assert!(a[110].gamma1_mm < a[10].gamma1_mm);
        // The depth is a Hertz part for the contact's radius plus a pulling
        // punch (the marker field draws both): the Hertz part's curvature,
        // (gamma1 - punch) / a^2, is the clean contact's on both branches
        // (within the percent Tatara's term moves it between sizes).
        let curvature = |r: &Reading| (r.gamma1_mm - r.gamma1_punch_mm) / (r.contact_radius_mm * r.contact_radius_mm);
        for k in [10, 40, 100, 110] {
            let (r, c_clean) = (&a[k], curvature(&clean[k]));
            assert!(r.gamma1_punch_mm < 0.0 && (curvature(r) / c_clean - 1.0).abs() < 0.015, "{r:?} vs {c_clean}");
        }
        assert!(clean.iter().all(|r| r.gamma1_punch_mm == 0.0));
        // Frame compliance: less depth at high force.
        let f = run(SimProfile {
            frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.01 }),
            ..Default::default()
        });
        assert!(f[60].gamma1_mm < clean[60].gamma1_mm - 0.01);
        // Drift moves the indenter: the contact is the clean one at the drifted
        // approach (only part of it is the gel's), and it shows on the way back.
        let d = run(SimProfile {
            thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 1e-4, vdot_mm_per_s2: 0.0 }),
            ..Default::default()
        });
        let m = NormalModel::new(p).unwrap();
        let at = |s: f64| m.solve(s).unwrap();
        assert!((d[60].gamma1_mm - at(3.0 + 60.0e-4).gamma1_mm).abs() < 1e-12);
        assert!((d[60].gamma2_mm - at(3.0 + 60.0e-4).gamma2_mm).abs() < 1e-12);
        let rise = d[60].gamma1_mm - clean[60].gamma1_mm;
        assert!(rise > 0.5 * 60.0e-4 && rise < 60.0e-4, "{rise}");
        assert!((d[90].gamma1_mm - at(1.5 + 90.0e-4).gamma1_mm).abs() < 1e-12);
        assert_eq!(d[0].gamma1_mm, 0.0);
        // Gain acts on the reading only.
        let g = run(SimProfile { sensor_gain: Some(sensor_gain::Params { g: 1.02 }), ..Default::default() });
        assert!((g[60].gamma1_mm / clean[60].gamma1_mm - 1.02).abs() < 1e-12);
    }

    #[test]
    fn rotation_backlash_offsets_the_return() {
        let p = pair();
        let st = NormalModel::new(p).unwrap().solve_for_gamma2(1.0).unwrap();
        let prof = SimProfile {
            rotation_backlash: Some(rotation_backlash::Params { b_deg: 0.3, engaged: true }),
            ..Default::default()
        };
        let cmds: Vec<CommandedPose> = [0.0, 4.0, 8.0, 7.8, 4.0, 0.0]
            .iter()
            .enumerate()
            .map(|(i, &r)| CommandedPose { t_s: i as f64, stage_mm: st.delta_mm, rot_deg: r })
            .collect();
        let r = simulate(p, &prof, &cmds).unwrap();
        let clean = simulate(p, &SimProfile::default(), &cmds).unwrap();
        assert!((r[2].theta1_deg - clean[2].theta1_deg).abs() < 1e-12);
        assert!((r[3].theta1_deg - r[2].theta1_deg).abs() < 1e-12, "flat step at the turn");
        let shift = r[4].theta1_deg - clean[4].theta1_deg;
        assert!((shift - 0.3 * clean[1].theta1_deg / 4.0).abs() < 1e-9, "{shift}");
    }
}
