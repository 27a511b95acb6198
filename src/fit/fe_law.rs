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
use super::full::{FullFit, ModelParams, fe_layer, layer_model_sd};
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
    /// The model's own error, relative, of E1 and nu1 on this recording.
    model_sd: [f64; 2],
    correction: Option<Correction>,
    /// The fit's E1, nu1 and their 95 % intervals (model error included).
    fit: [[f64; 3]; 2],
    /// Where the friction correction was taken.
    anchor: ModelParams,
    /// Whether that was given (where a previous pass's explanation ended)
    /// rather than the full fit's optimum.
    anchor_given: bool,
}

impl LayeredBase {
    /// The layer model the full fit `full` stands on, with its friction
    /// correction taken at `at` (the fit's optimum when `None`), or `None`
    /// without a declared layer the FE model takes.
    pub fn of(rec: &Recording, full: &FullFit, at: Option<&ModelParams>) -> Result<Option<Self>, FitError> {
        let Some(layer) = fe_layer(rec) else {
            return Ok(None);
        };
        let p = &at.copied().unwrap_or_else(|| full.params());
        let ind = rec.meta.indenter;
        let forward = crate::layer::forward(&layer, ind.e_mpa, ind.nu, ind.r_mm)?;
        Ok(Some(Self {
            forward,
            layer,
            indenter_e_mpa: ind.e_mpa,
            indenter_nu: ind.nu,
            indenter_r_mm: ind.r_mm,
            friction: p.contact_friction.or(full.contact_friction),
            large_strain: p.large_strain,
            model_sd: layer_model_sd(rec, &full.params()),
            correction: friction_correction(rec, p, None)?,
            fit: [
                [full.e1_mpa, full.ci95.e1_mpa[0], full.ci95.e1_mpa[1]],
                [full.nu1, full.ci95.nu1[0], full.ci95.nu1[1]],
            ],
            anchor: *p,
            anchor_given: at.is_some(),
        }))
    }

    /// Whether the friction correction, linear about where it was taken, still
    /// holds at `p`: E1 within 0.5 %, nu1 within 0.005, z0 within 5 µm and the
    /// friction within 10 % of there (always, at large strain, which has none).
    /// A refit that ends further away is taken again from a correction taken
    /// there (docs/diagnosis.md, "On a declared layer": a drifting frame took
    /// the fit 5 % off in E1, and the correction's linear form misread the
    /// twist at the truth by 0.18°).
    pub fn anchored_near(&self, p: &ModelParams) -> bool {
        let a = &self.anchor;
        self.correction.is_none()
            || ((p.e1_mpa / a.e1_mpa - 1.0).abs() < 5e-3
                && (p.nu1 - a.nu1).abs() < 5e-3
                && (p.contact_offset_mm - a.contact_offset_mm).abs() < 5e-3
                && match (p.contact_friction, a.contact_friction) {
                    (Some(x), Some(y)) => (x / y - 1.0).abs() < 0.1,
                    (x, y) => x == y,
                })
    }

    /// Where a previous pass's explanation ended, when the correction was
    /// taken there: a refit on this model starts from there too (a baseline
    /// that absorbed an effect can sit where the twist sticks, where the
    /// friction's cost is flat and a refit started on it stays).
    pub fn previous_explanation(&self) -> Option<&ModelParams> {
        self.anchor_given.then_some(&self.anchor)
    }

    /// The layer model's parameters at E1, nu1, z0 and `friction`.
    pub fn params(&self, e1_mpa: f64, nu1: f64, z0_mm: f64, friction: Option<f64>) -> ModelParams {
        ModelParams {
            e1_mpa,
            nu1,
            contact_offset_mm: z0_mm,
            contact_friction: friction,
            large_strain: self.large_strain,
        }
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
        self.model_sd
    }

    /// Whether the model is the large-strain one.
    pub fn large_strain(&self) -> bool {
        self.large_strain
    }

    /// The Coulomb friction the twist is limited by (`None`: it sticks).
    pub fn friction(&self) -> Option<f64> {
        self.friction
    }

    /// The contact law at elastomer modulus `e1_mpa`, Poisson's ratio `nu1`
    /// and the friction `friction` between indenter and gel (`None`: sticks).
    pub fn law(&self, e1_mpa: f64, nu1: f64, friction: Option<f64>) -> Result<Arc<dyn ContactLaw>, FitError> {
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
            Some(fem::hyper::LargeStrainTable::builtin()?.at_groups(&groups))
        } else {
            None
        };
        Ok(Arc::new(FeLaw::new(self.forward.clone(), e1_mpa, nu1, friction.unwrap_or(f64::INFINITY), table)))
    }

    /// Add the friction correction at (E1, nu1, z0, friction) to readings of
    /// the recording's samples (one per sample, recording order), through the
    /// sensor's `gain`; readings without contact stay zero.
    pub fn correct(
        &self,
        readings: &mut [Reading],
        e1_mpa: f64,
        nu1: f64,
        z0_mm: f64,
        friction: Option<f64>,
        gain: f64,
    ) {
        let Some(c) = &self.correction else {
            return;
        };
        let p = self.params(e1_mpa, nu1, z0_mm, friction);
        for (r, (dg, dt)) in readings.iter_mut().zip(c.at(&p)) {
            if r.in_contact {
                r.gamma1_mm += gain * dg;
                r.gamma1_true_mm += dg;
                r.theta1_deg += dt;
            }
        }
    }
}

/// The disc the linear layer model's theta1 is taken over: the contact's
/// (the sensor's r <= a), and at large strain the nodes' edge, over which
/// the linear side of the neo-Hookean reference's twist ratios was taken
/// (docs/physics.md, "theta1 over the contact").
pub(crate) fn twist_disc(large_strain: bool) -> fem::forward::TwistDisc {
    match large_strain {
        true => fem::forward::TwistDisc::NodeEdge,
        false => fem::forward::TwistDisc::Contact,
    }
}

/// One parameter set of the FE layer model as a contact law: the
/// frictionless press and the twist limited by the fit's friction, read off
/// the rig's tabulated law (docs/fem.md, "The tabulated law") and solved on
/// the FE model where the table ends (each such approach solved once and
/// kept); at large strain the tabulated ratios of the neo-Hookean reference
/// at each approach. The fit's friction correction, added per sample
/// (`LayeredBase::correct`), is what friction adds to it.
struct FeLaw {
    forward: Arc<fem::forward::Forward>,
    e1_mpa: f64,
    nu1: f64,
    /// The tabulated law at this parameter set; `None` off the table's materials.
    tabulated: Option<Arc<fem::tabulated::LawAt>>,
    /// The FE model at this parameter set, built when the table first ends.
    model: std::sync::OnceLock<fem::forward::Model>,
    friction: f64,
    /// The large-strain table's interpolation at the law's materials (taken
    /// once: the groups other than the approach are the law's).
    table: Option<fem::hyper::AtGroups<'static>>,
    indenter_r_mm: f64,
    solved: Mutex<HashMap<u64, Arc<Solved>>>,
}

/// One approach of [`FeLaw`] solved on the FE model, once: the state, its
/// contact radius and what its twists share (prepared on the first twist).
struct Solved {
    state: fem::ContactState,
    radius_mm: f64,
    twist: std::sync::OnceLock<Option<fem::forward::TwistSetup>>,
}

impl std::fmt::Debug for FeLaw {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FeLaw").field("friction", &self.friction).field("large_strain", &self.table.is_some()).finish()
    }
}

impl FeLaw {
    fn new(
        forward: Arc<fem::forward::Forward>,
        e1_mpa: f64,
        nu1: f64,
        friction: f64,
        table: Option<fem::hyper::AtGroups<'static>>,
    ) -> Self {
        // A rig whose law cannot be tabulated is solved on the FE model throughout.
        let tabulated = forward.tabulated_over(e1_mpa, nu1, twist_disc(table.is_some()));
        let indenter_r_mm = forward.indenter_radius_mm();
        FeLaw {
            forward,
            e1_mpa,
            nu1,
            tabulated,
            model: std::sync::OnceLock::new(),
            friction,
            table,
            indenter_r_mm,
            solved: Mutex::new(HashMap::new()),
        }
    }

    fn model(&self) -> &fem::forward::Model {
        self.model.get_or_init(|| self.forward.model(self.e1_mpa, self.nu1))
    }

    fn state(&self, delta_mm: f64) -> Result<Arc<Solved>, String> {
        let key = delta_mm.to_bits();
        if let Some(st) = fem::lock_cache(&self.solved).get(&key).cloned() {
            return Ok(st);
        }
        let state = self.model().normal(delta_mm).map_err(|e| e.to_string())?;
        let radius_mm = if state.force_n > 0.0 { self.model().contact_radius_mm(&state) } else { 0.0 };
        let solved = Arc::new(Solved { state, radius_mm, twist: std::sync::OnceLock::new() });
        fem::lock_cache(&self.solved).insert(key, solved.clone());
        Ok(solved)
    }

    /// The large-strain ratio of gamma1 at approach `delta_mm`; 1 at small strain.
    fn gamma1_ratio(&self, delta_mm: f64) -> f64 {
        self.table.as_ref().map_or(1.0, |at| at.gamma1_ratio(delta_mm.max(0.0) / self.indenter_r_mm).ratio)
    }

    /// The large-strain ratio of the twist at `twist_deg` under the law's
    /// friction at approach `delta_mm`; 1 at small strain.
    fn twist_ratio(&self, delta_mm: f64, twist_deg: f64) -> f64 {
        self.table.as_ref().map_or(1.0, |at| {
            at.frictional_twist_ratio(delta_mm.max(0.0) / self.indenter_r_mm, twist_deg, self.friction).ratio
        })
    }

    /// The linear press at `delta_mm`: (gamma1, force, contact radius).
    fn press(&self, delta_mm: f64) -> Result<(f64, f64, f64), String> {
        if delta_mm <= 0.0 {
            return Ok((0.0, 0.0, 0.0));
        }
        let read = self
            .tabulated
            .as_ref()
            .and_then(|t| Some((t.gamma1_mm(delta_mm)?, t.force_n(delta_mm)?, t.contact_radius_mm(delta_mm)?)));
        match read {
            Some(v) => Ok(v),
            // On the FE model's own mesh, plus what the limit adds there.
            None => self.state(delta_mm).map(|s| {
                let mesh = self.tabulated.as_ref().and_then(|t| t.mesh_gamma1_mm(delta_mm)).unwrap_or(0.0);
                (s.state.gamma1_mm + mesh, s.state.force_n, s.radius_mm)
            }),
        }
    }
}

impl ContactLaw for FeLaw {
    fn normal(&self, delta_mm: f64) -> Result<LawState, String> {
        let (gamma1_mm, force_n, contact_radius_mm) = self.press(delta_mm)?;
        let gamma1_mm = gamma1_mm * self.gamma1_ratio(delta_mm);
        Ok(LawState { gamma1_mm, gamma2_mm: delta_mm - gamma1_mm, force_n, contact_radius_mm })
    }

    fn theta1_deg(&self, delta_mm: f64, twist_deg: f64) -> Result<f64, String> {
        if delta_mm <= 0.0 {
            return Ok(0.0);
        }
        let twist = twist_deg.to_radians();
        let read = self.tabulated.as_ref().and_then(|t| t.theta1_rad(delta_mm, twist.abs(), self.friction));
        let t = match read {
            Some(t) => t.to_degrees(),
            None => {
                let solved = self.state(delta_mm)?;
                let disc = twist_disc(self.table.is_some());
                let setup =
                    solved.twist.get_or_init(|| self.model().twist_setup_over(&solved.state, self.friction, disc));
                setup.as_ref().and_then(|s| self.model().theta1_rad_at(s, twist.abs())).map_or(0.0, f64::to_degrees)
            }
        };
        Ok(t * self.twist_ratio(delta_mm, twist_deg) * twist.signum())
    }
}

/// Approach steps of a simulated truth's frictional path (docs/physics.md,
/// "The layer in the generator and the emulated rig"): its states are interpolated linearly
/// between them.
const TRUTH_PATH_STEPS: usize = 400;

/// The deepest indenter deformation a simulated truth's path reaches, in
/// indenter radii: past the generator's 0.2, and past the torsion depth's
/// search above it.
const TRUTH_GAMMA2_R2: f64 = 0.3;

/// The FE layer model (linear elasticity) pressed with Coulomb friction `mu`
/// along a monotone approach and twisted under the same friction: the
/// simulated truth of a gel layer (`easycalib simulate --thickness-mm`). Its
/// states are those the fit's frictional model gives at each depth (it, too,
/// follows the approach from first touch in depth order), taken on a path of
/// [`TRUTH_PATH_STEPS`] to where the indenter deforms by [`TRUTH_GAMMA2_R2`]
/// of its radius (or to the deepest depth the model solves) and interpolated
/// between them.
pub fn frictional_truth(
    layer: Layer,
    indenter: sim::physics::Body,
    e1_mpa: f64,
    nu1: f64,
    mu: f64,
) -> Result<Arc<dyn ContactLaw>, FitError> {
    if !(e1_mpa.is_finite() && e1_mpa > 0.0 && (0.0..=0.5).contains(&nu1) && mu >= 0.0) {
        return Err(FitError::Model(format!("E1 {e1_mpa} MPa, nu1 {nu1}, friction {mu} outside the layer model")));
    }
    let forward = crate::layer::forward(&layer, indenter.e_mpa, indenter.nu, indenter.r_mm)?;
    let model = forward.model(e1_mpa, nu1);
    // How deep to go: double the approach until the indenter deforms enough
    // (frictionless, cheap) or the model stops solving.
    let want = TRUTH_GAMMA2_R2 * indenter.r_mm;
    let mut deepest = 0.0;
    let mut delta = want;
    for _ in 0..8 {
        match model.normal(delta) {
            Ok(st) if st.gamma2_mm >= want => {
                deepest = delta;
                break;
            }
            Ok(_) => {
                deepest = delta;
                delta *= 1.5;
            }
            Err(_) => break,
        }
    }
    if deepest <= 0.0 {
        return Err(FitError::Model("the layer model solves no contact for this indenter".into()));
    }
    let deltas: Vec<f64> = (1..=TRUTH_PATH_STEPS).map(|i| deepest * i as f64 / TRUTH_PATH_STEPS as f64).collect();
    let states = model.normal_path(&deltas, mu, deepest / TRUTH_PATH_STEPS as f64)?;
    let gel = (layer, indenter, e1_mpa, nu1);
    let mesh = forward.tabulated_at(e1_mpa, nu1);
    Ok(Arc::new(PathLaw { deltas, states, model, mu, gel, mesh, surface: std::sync::OnceLock::new() }))
}

/// A frictional path's states as a contact law (see [`frictional_truth`]).
struct PathLaw {
    deltas: Vec<f64>,
    states: Vec<fem::ContactState>,
    model: fem::forward::Model,
    mu: f64,
    /// The rig's tabulated law at the gel, for what taking the path's mesh
    /// to zero element size adds to gamma1 (as the fit's law has it).
    mesh: Option<Arc<fem::tabulated::LawAt>>,
    /// The gel's surface (built when the simulated sensor first asks).
    gel: (Layer, sim::physics::Body, f64, f64),
    surface: std::sync::OnceLock<Option<Arc<sim::sensor::shape::SurfaceShape>>>,
}

impl std::fmt::Debug for PathLaw {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PathLaw").field("deepest_mm", &self.deltas.last()).field("friction", &self.mu).finish()
    }
}

impl PathLaw {
    /// What taking the path's mesh to zero element size adds to gamma1 at
    /// `delta_mm` (docs/physics.md, "Mesh convergence").
    fn mesh_gamma1_mm(&self, delta_mm: f64) -> f64 {
        self.mesh.as_ref().and_then(|at| at.mesh_gamma1_mm(delta_mm)).unwrap_or(0.0)
    }

    /// The two path states around `delta_mm` and the weight of the upper one
    /// (the lower is the unloaded contact below the first step).
    fn around(&self, delta_mm: f64) -> Result<(Option<&fem::ContactState>, &fem::ContactState, f64), String> {
        let last = *self.deltas.last().unwrap_or(&0.0);
        if !(delta_mm > 0.0 && delta_mm <= last) {
            return Err(format!("approach {delta_mm:.4} mm outside the simulated path (0, {last:.4}] mm"));
        }
        let i = self.deltas.partition_point(|&d| d < delta_mm).min(self.deltas.len() - 1);
        let (lo, lo_state) = match i.checked_sub(1) {
            Some(j) => (self.deltas[j], Some(&self.states[j])),
            None => (0.0, None),
        };
        Ok((lo_state, &self.states[i], (delta_mm - lo) / (self.deltas[i] - lo)))
    }
}

impl ContactLaw for PathLaw {
    fn normal(&self, delta_mm: f64) -> Result<LawState, String> {
        let (lo, hi, w) = self.around(delta_mm)?;
        let mix = |f: fn(&fem::ContactState) -> f64| lo.map_or(0.0, f) * (1.0 - w) + f(hi) * w;
        let gamma1_mm = mix(|s| s.gamma1_mm) + self.mesh_gamma1_mm(delta_mm);
        // The edge between the two states, continuous in the approach; its
        // square is what grows in proportion to the approach (Hertz: a² = R
        // delta), from nothing below the first state.
        let edge2 = |s: &fem::ContactState| self.model.contact_radius_mm(s).powi(2);
        let a2 = lo.map_or(0.0, edge2) * (1.0 - w) + edge2(hi) * w;
        Ok(LawState {
            gamma1_mm,
            gamma2_mm: delta_mm - gamma1_mm,
            force_n: mix(|s| s.force_n),
            contact_radius_mm: a2.sqrt(),
        })
    }

    fn theta1_deg(&self, delta_mm: f64, twist_deg: f64) -> Result<f64, String> {
        let (lo, hi, w) = self.around(delta_mm)?;
        let twist = twist_deg.to_radians();
        let at = |s: &fem::ContactState| self.model.theta1_rad(s, twist.abs(), self.mu).unwrap_or(0.0);
        Ok((lo.map_or(0.0, at) * (1.0 - w) + at(hi) * w).to_degrees() * twist.signum())
    }

    /// The true gel's own field shape (the same FE layer on its base,
    /// frictionless; docs/sensing.md, "On a layer"), so the simulated sensor
    /// draws what the layer shows rather than Hertz's field. `None` only if the layer
    /// model cannot give it (`rig::emulated::on_declared_layer` then refuses
    /// the layer).
    fn surface(&self) -> Option<Arc<sim::sensor::shape::SurfaceShape>> {
        self.surface
            .get_or_init(|| {
                let (layer, indenter, e1, nu1) = self.gel;
                crate::sensing::LayerSurface::of_gel(layer, indenter, e1, nu1).ok().map(|s| s.shape)
            })
            .clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The simulated sensor draws its marker field with the law's contact
    /// radius, so it must grow with the approach as a contact's radius does,
    /// not step by the mesh's 0.06 mm as the nodes touch down: a field drawn
    /// on such a staircase reads micrometres off at small contacts
    /// (docs/physics.md, "The layer in the generator and the emulated rig").
    /// Over a press in 2 µm steps (the Tac3D-like pair on a 5 mm bonded gel)
    /// a² may not grow by more than three times its median step (a node
    /// touching down at a = 1 mm steps a² by 0.12 mm², 22 median steps). Its
    /// value is checked against the analytical layer in `fem`
    /// (`the_contact_radius_is_the_analytical_layers`).
    #[test]
    fn the_layer_laws_contact_radius_grows_smoothly_with_the_approach() {
        let layer = Layer { thickness_mm: 5.0, base: sim::physics::LayerBase::Bonded, thickness_tol_mm: None };
        let indenter = sim::physics::Body::new(1.1, 0.39, 5.0);
        let path = frictional_truth(layer, indenter, 0.33, 0.39, 0.4).expect("the layer simulates");
        let forward = fem::forward::Forward::cached(5.0, 1.1, 0.39, 5.0).expect("the layer model");
        let frictionless = FeLaw::new(forward, 0.33, 0.39, 0.4, None);
        for (name, law) in [("frictional path", path.as_ref()), ("frictionless", &frictionless as &dyn ContactLaw)] {
            let a2: Vec<f64> =
                (10..=600).map(|k| law.normal(0.002 * k as f64).expect("in range").contact_radius_mm.powi(2)).collect();
            let mut steps: Vec<f64> = a2.windows(2).map(|w| w[1] - w[0]).collect();
            let (least, most) = steps.iter().fold((f64::INFINITY, 0.0f64), |(l, m), &s| (l.min(s), m.max(s)));
            steps.sort_by(f64::total_cmp);
            let median = steps[steps.len() / 2];
            println!("{name}: a² steps {least:.5}..{most:.5} mm², median {median:.5} mm²");
            assert!(least >= 0.0, "{name}: the contact shrinks while pressing ({least} mm²)");
            assert!(most <= 3.0 * median, "{name}: a² jumps by {most} mm² (median step {median})");
        }
    }
}
