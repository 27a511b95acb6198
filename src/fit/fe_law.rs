//! The declared layer's contact as a law the rig's effects wrap
//! (`sim::effects::ContactLaw`; docs/physics.md, "Rig effects on a declared
//! layer"): the diagnosis refits the rig-level effects of the library on the
//! same FE layer model the fit ends on, with its friction and its strain
//! model held where the fit left them.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use sim::effects::{ContactLaw, LawState, Reading};
use sim::physics::Layer;
use sim::recording::Recording;

use super::FitError;
use super::full::{FullFit, LAYER_MODEL_SD_E1, LAYER_MODEL_SD_NU1, ModelParams, fe_layer};
use super::layer_model::{Correction, friction_correction};

/// The FE layer model of a fitted recording, as a family of contact laws in
/// E1 and nu1: the indenter and the layer of the recording, the friction and
/// the strain model of the fit, and the fit's deferred friction correction
/// (the frictional press minus the frictionless one, per sample, linear in
/// the parameters about the fit's optimum).
pub struct LayeredBase {
    forward: Arc<fem::forward::Forward>,
    layer: Layer,
    indenter_e_mpa: f64,
    indenter_nu: f64,
    indenter_r_mm: f64,
    friction: Option<f64>,
    large_strain: bool,
    correction: Option<Correction>,
    /// The fit's E1, nu1 and their 95 % intervals (model error included).
    fit: [[f64; 3]; 2],
}

impl LayeredBase {
    /// The layer model the full fit `full` stands on, or `None` without a
    /// declared layer the FE model takes.
    pub fn of(rec: &Recording, full: &FullFit) -> Result<Option<Self>, FitError> {
        let Some(layer) = fe_layer(rec) else {
            return Ok(None);
        };
        let p = &full.params();
        let ind = rec.meta.indenter;
        let forward = fem::forward::Forward::cached(layer.thickness_mm, ind.e_mpa, ind.nu, ind.r_mm)?;
        Ok(Some(Self {
            forward,
            layer,
            indenter_e_mpa: ind.e_mpa,
            indenter_nu: ind.nu,
            indenter_r_mm: ind.r_mm,
            friction: p.contact_friction,
            large_strain: p.large_strain,
            correction: friction_correction(rec, p, None)?,
            fit: [
                [full.e1_mpa, full.ci95.e1_mpa[0], full.ci95.e1_mpa[1]],
                [full.nu1, full.ci95.nu1[0], full.ci95.nu1[1]],
            ],
        }))
    }

    /// The full fit's E1 and nu1, each as (value, 95 % interval), the model's
    /// own error included: what a diagnosis that names nothing reports, so
    /// that it and `fit` agree.
    pub fn fitted(&self) -> [(f64, [f64; 2]); 2] {
        self.fit.map(|[v, lo, hi]| (v, [lo, hi]))
    }

    /// The model's own approximation error, relative, one standard deviation,
    /// of E1 and nu1 (docs/physics.md section 3): added in quadrature to a
    /// refit's intervals.
    pub fn relative_model_sd(&self) -> [f64; 2] {
        if self.large_strain {
            [super::large_strain::MODEL_SD_E1, super::large_strain::MODEL_SD_NU1]
        } else {
            [LAYER_MODEL_SD_E1, LAYER_MODEL_SD_NU1]
        }
    }

    /// Whether the model is the large-strain one.
    pub fn large_strain(&self) -> bool {
        self.large_strain
    }

    /// The Coulomb friction the twist is limited by (`None`: it sticks).
    pub fn friction(&self) -> Option<f64> {
        self.friction
    }

    /// The contact law at elastomer modulus `e1_mpa` and Poisson's ratio `nu1`.
    pub fn law(&self, e1_mpa: f64, nu1: f64) -> Result<Arc<dyn ContactLaw>, FitError> {
        if !(e1_mpa.is_finite() && e1_mpa > 0.0 && (0.0..=0.5).contains(&nu1)) {
            return Err(FitError::Model(format!("E1 {e1_mpa} MPa, nu1 {nu1} outside the layer model")));
        }
        let table = if self.large_strain {
            let groups = fem::hyper::Groups {
                e2_over_e1: self.indenter_e_mpa / e1_mpa,
                nu1,
                nu2: self.indenter_nu,
                h_over_r2: self.layer.thickness_mm / self.indenter_r_mm,
                delta_over_r2: 0.0,
            };
            Some((fem::hyper::LargeStrainTable::builtin()?, groups))
        } else {
            None
        };
        Ok(Arc::new(FeLaw {
            model: self.forward.model(e1_mpa, nu1),
            friction: self.friction.unwrap_or(f64::INFINITY),
            table,
            indenter_r_mm: self.indenter_r_mm,
            solved: Mutex::new(HashMap::new()),
        }))
    }

    /// Add the friction correction at (E1, nu1, z0) to readings of the
    /// recording's samples (one per sample, recording order), through the
    /// sensor's `gain`; readings without contact stay zero.
    pub fn correct(&self, readings: &mut [Reading], e1_mpa: f64, nu1: f64, z0_mm: f64, gain: f64) {
        let Some(c) = &self.correction else {
            return;
        };
        let p = ModelParams {
            e1_mpa,
            nu1,
            contact_offset_mm: z0_mm,
            contact_friction: self.friction,
            large_strain: self.large_strain,
        };
        for (r, (dg, dt)) in readings.iter_mut().zip(c.at(&p)) {
            if r.in_contact {
                r.gamma1_mm += gain * dg;
                r.gamma1_true_mm += dg;
                r.theta1_deg += dt;
            }
        }
    }
}

/// One parameter set of the FE layer model as a contact law: the
/// frictionless press (each approach solved once and kept), the twist
/// limited by the fit's friction, and at large strain the tabulated ratios
/// of the neo-Hookean reference at each approach.
struct FeLaw {
    model: fem::forward::Model,
    friction: f64,
    table: Option<(&'static fem::hyper::LargeStrainTable, fem::hyper::Groups)>,
    indenter_r_mm: f64,
    solved: Mutex<HashMap<u64, fem::ContactState>>,
}

impl std::fmt::Debug for FeLaw {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FeLaw").field("friction", &self.friction).field("large_strain", &self.table.is_some()).finish()
    }
}

impl FeLaw {
    fn state(&self, delta_mm: f64) -> Result<fem::ContactState, String> {
        let key = delta_mm.to_bits();
        if let Some(st) = self.solved.lock().ok().and_then(|m| m.get(&key).cloned()) {
            return Ok(st);
        }
        let st = self.model.normal(delta_mm).map_err(|e| e.to_string())?;
        if let Ok(mut m) = self.solved.lock() {
            m.insert(key, st.clone());
        }
        Ok(st)
    }

    /// The large-strain ratios (gamma1, twist) at approach `delta_mm`; 1 at small strain.
    fn ratios(&self, delta_mm: f64) -> (f64, f64) {
        self.table.map_or((1.0, 1.0), |(t, g)| {
            let g = fem::hyper::Groups { delta_over_r2: delta_mm.max(0.0) / self.indenter_r_mm, ..g };
            (t.gamma1_ratio(&g).ratio, t.twist_ratio(&g).ratio)
        })
    }
}

impl ContactLaw for FeLaw {
    fn normal(&self, delta_mm: f64) -> Result<LawState, String> {
        let st = self.state(delta_mm)?;
        let gamma1_mm = st.gamma1_mm * self.ratios(delta_mm).0;
        // The contact's edge lies between the outermost node in contact and the next.
        let [inner, outer] = st.contact_radius_mm;
        Ok(LawState {
            gamma1_mm,
            gamma2_mm: delta_mm - gamma1_mm,
            force_n: st.force_n,
            contact_radius_mm: if st.force_n > 0.0 { 0.5 * (inner + outer) } else { 0.0 },
        })
    }

    fn theta1_deg(&self, delta_mm: f64, twist_deg: f64) -> Result<f64, String> {
        let st = self.state(delta_mm)?;
        let twist = twist_deg.to_radians();
        let t = self.model.theta1_rad(&st, twist.abs(), self.friction).map_or(0.0, |t| t.to_degrees());
        Ok(t * self.ratios(delta_mm).1 * twist.signum())
    }
}
