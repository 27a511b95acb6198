//! A whole calibration on the large-strain reference (docs/physics.md, "Large
//! strain"): the normal sweep in even stage steps to the depth where the
//! indenter's deformation reaches beta R2, then the twist sweep there. This is
//! `easycalib simulate --fidelity fe`.

use std::sync::atomic::{AtomicUsize, Ordering};

use super::{LargeState, LargeStrainContact};
use crate::FemError;
use crate::elastic::Material;
use crate::mesh::Mesh;

/// What to sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepPlan {
    /// Target gamma2 / R2 of the deepest normal sample (the torsion depth).
    pub beta: f64,
    /// Even stage steps from first contact to that depth.
    pub normal_steps: usize,
    /// Platform twists of the torsion sweep, degrees (increasing from 0).
    pub twists_deg: Vec<f64>,
    /// Coulomb friction between the bodies while twisting.
    pub friction: f64,
}

/// The sweeps' results, noise-free.
#[derive(Debug, Clone, PartialEq)]
pub struct Sweep {
    /// One state per stage step, the first at zero approach.
    pub normal: Vec<LargeState>,
    /// (platform twist, theta1), degrees, at the deepest state.
    pub torsion_deg: Vec<(f64, f64)>,
    /// gamma2 / R2 of the deepest state: the plan's beta, or less where the
    /// reference's iteration stopped settling before it (a stiff indenter
    /// pressed deep into a thin gel; docs/physics.md, "Large strain").
    pub beta_reached: f64,
}

/// Load step while searching for the torsion depth, mm.
const SEARCH_STEP_MM: f64 = 0.05;

impl LargeStrainContact {
    /// A gel layer of `thickness_mm` bonded to its window (as wide as the linear
    /// reference's, with the same mesh) and a hemisphere of `indenter_radius_mm`.
    pub fn for_layer(
        thickness_mm: f64,
        gel: Material,
        indenter: Material,
        indenter_radius_mm: f64,
    ) -> Result<Self, FemError> {
        Self::for_layer_at(
            crate::Base::Bonded,
            thickness_mm,
            gel,
            indenter,
            indenter_radius_mm,
            crate::forward::FINE_MM,
        )
    }

    /// [`Self::for_layer`] with elements of `fine_mm` at the contact (the
    /// hemisphere's segments matched to them), on a gel sitting on its window
    /// as `base` says.
    pub fn for_layer_at(
        base: crate::Base,
        thickness_mm: f64,
        gel: Material,
        indenter: Material,
        indenter_radius_mm: f64,
        fine_mm: f64,
    ) -> Result<Self, FemError> {
        let gel_mesh = crate::forward::gel_mesh_at(thickness_mm, fine_mm)?.on_base(base);
        let rs: Vec<f64> = gel_mesh.surface_radii().into_iter().filter(|&r| r < 0.97 * indenter_radius_mm).collect();
        let hemi = Mesh::hemisphere(indenter_radius_mm, &rs, crate::forward::hemisphere_segments(fine_mm))?;
        Self::new(gel_mesh, gel, hemi, indenter, indenter_radius_mm)
    }
}

/// Runs `plan` on fresh contacts from `build` (one to find the depth, one to
/// sweep: the frictionless normal contact does not depend on the path).
pub fn calibration_sweep(
    build: impl Fn() -> Result<LargeStrainContact, FemError>,
    indenter_radius_mm: f64,
    plan: &SweepPlan,
) -> Result<Sweep, FemError> {
    let stages = sweep_stages(&mut build()?, indenter_radius_mm, plan)?;
    let mut sweep = build()?;
    let normal = press(&mut sweep, &stages, &AtomicUsize::new(usize::MAX)).ended(stages.len(), plan)?;
    let deepest = normal.last().ok_or_else(|| FemError::Invalid("an empty sweep".into()))?;
    let twists: Vec<f64> = plan.twists_deg.iter().map(|d| d.to_radians()).collect();
    let theta = sweep.theta1_rad(deepest, &twists, plan.friction)?;
    let torsion_deg = plan.twists_deg.iter().zip(&theta).map(|(&d, t)| (d, t.to_degrees())).collect();
    let beta_reached = deepest.gamma2_mm / indenter_radius_mm;
    Ok(Sweep { normal, torsion_deg, beta_reached })
}

/// The stage positions of `plan`'s normal sweep, from first touch to the
/// depth where the indenter's deformation reaches beta R2, found by pressing
/// `search` in steps of [`SEARCH_STEP_MM`] (and interpolating in the last).
fn sweep_stages(
    search: &mut LargeStrainContact,
    indenter_radius_mm: f64,
    plan: &SweepPlan,
) -> Result<Vec<f64>, FemError> {
    if !(plan.beta > 0.0 && plan.beta < 0.3 && plan.normal_steps >= 2) {
        return Err(FemError::Invalid(format!("sweep to beta {} in {} steps", plan.beta, plan.normal_steps)));
    }
    let target = plan.beta * indenter_radius_mm;
    let mut last = search.step_to(0.0)?;
    let depth = loop {
        // A step that does not settle (or whose tangent gives out, or that
        // turns an element inside out) ends the search at the deepest state
        // that did, once a quarter of the target was reached: the sweep then
        // says how deep it got.
        let next = match search.solve_path(&[last.delta_mm + SEARCH_STEP_MM], SEARCH_STEP_MM) {
            Ok(mut v) => v.pop().ok_or_else(|| FemError::Invalid("an empty load step".into()))?,
            Err(e) if ends_the_sweep(&e) && last.gamma2_mm > 0.25 * target => {
                break last.delta_mm;
            }
            Err(e) => return Err(e),
        };
        if next.gamma2_mm >= target {
            let t = (target - last.gamma2_mm) / (next.gamma2_mm - last.gamma2_mm);
            break last.delta_mm + t * (next.delta_mm - last.delta_mm);
        }
        if next.delta_mm > 4.0 * indenter_radius_mm {
            return Err(FemError::Invalid(format!("gamma2 never reaches {target} mm")));
        }
        last = next;
    };
    Ok((0..=plan.normal_steps).map(|k| depth * k as f64 / plan.normal_steps as f64).collect())
}

/// A contact pressed through stages in order: the states it settled, and
/// what stopped it before the last stage, if anything did.
struct Pressed {
    states: Vec<LargeState>,
    stopped: Option<FemError>,
}

/// Presses `contact` through `stages` in order until one fails or `limit`
/// stages are done (`limit` may fall while it runs: another thread's sweep
/// that ended says how far this one is still wanted).
fn press(contact: &mut LargeStrainContact, stages: &[f64], limit: &AtomicUsize) -> Pressed {
    let mut states = Vec::with_capacity(stages.len());
    for &stage in stages {
        if states.len() >= limit.load(Ordering::Relaxed) {
            break;
        }
        match contact.solve_path(&[stage], SEARCH_STEP_MM) {
            Ok(v) => states.extend(v),
            Err(e) => return Pressed { states, stopped: Some(e) },
        }
    }
    Pressed { states, stopped: None }
}

impl Pressed {
    /// The sweep's first `wanted` states, or fewer where the contact stopped
    /// settling before them (the same trouble the depth's search met can come
    /// back at a depth it passed: the load steps fall elsewhere), once a
    /// quarter of the plan's steps are done; any other failure before
    /// `wanted` is the sweep's error.
    fn ended(mut self, wanted: usize, plan: &SweepPlan) -> Result<Vec<LargeState>, FemError> {
        match self.stopped {
            Some(e)
                if self.states.len() < wanted && !(ends_the_sweep(&e) && 4 * self.states.len() > plan.normal_steps) =>
            {
                Err(e)
            }
            _ => {
                self.states.truncate(wanted);
                Ok(self.states)
            }
        }
    }
}

/// [`calibration_sweep`] on a gel layer of `thickness_mm` bonded to its
/// window, taken to zero element size as the large-strain table is
/// (docs/physics.md, "Mesh convergence"): the sweep on the table's coarse
/// mesh ([`super::TABLE_COARSE_MM`]) sets the stage positions, the table's
/// fine mesh ([`super::TABLE_FINE_MM`]) presses to the same ones, and each
/// state's gamma1 and gamma2 are the first-order limit of the two
/// ([`super::mesh_extrapolated`]); the rest of a state and the twists are the
/// fine mesh's. Where the fine mesh stops settling first, the sweep ends
/// there. The two meshes press on two threads once the coarse mesh has found
/// the stages (the fine mesh's press is most of the time: the default pair's
/// recording took 164 s in turn and 123 s at once).
pub fn converged_layer_sweep(
    thickness_mm: f64,
    gel: Material,
    indenter: Material,
    indenter_radius_mm: f64,
    plan: &SweepPlan,
) -> Result<Sweep, FemError> {
    use super::{TABLE_COARSE_MM, TABLE_FINE_MM, mesh_extrapolated};
    let at = |fine_mm: f64| {
        LargeStrainContact::for_layer_at(crate::Base::Bonded, thickness_mm, gel, indenter, indenter_radius_mm, fine_mm)
    };
    let stages = sweep_stages(&mut at(TABLE_COARSE_MM)?, indenter_radius_mm, plan)?;
    // The two meshes press through the same stages at once (each press is
    // serial); the coarse sweep's end bounds the fine one's, as in turn.
    let wanted = AtomicUsize::new(usize::MAX);
    let (coarse, fine) = std::thread::scope(|scope| {
        let coarse = scope.spawn(|| {
            let pressed = at(TABLE_COARSE_MM).map(|mut c| press(&mut c, &stages, &AtomicUsize::new(usize::MAX)));
            let normal = pressed.and_then(|p| p.ended(stages.len(), plan));
            wanted.store(normal.as_ref().map_or(0, Vec::len), Ordering::Relaxed);
            normal
        });
        let fine = at(TABLE_FINE_MM).map(|mut f| {
            let pressed = press(&mut f, &stages, &wanted);
            (f, pressed)
        });
        let coarse = coarse.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        (coarse, fine)
    });
    let coarse = coarse?;
    let (fine, pressed) = fine?;
    let fine_normal = pressed.ended(coarse.len(), plan)?;
    let normal: Vec<(LargeState, f64, f64)> = fine_normal
        .into_iter()
        .zip(&coarse)
        .map(|(f, c)| {
            let gamma1_mm = mesh_extrapolated(f.gamma1_mm, c.gamma1_mm, TABLE_FINE_MM, TABLE_COARSE_MM);
            let gamma2_mm = mesh_extrapolated(f.gamma2_mm, c.gamma2_mm, TABLE_FINE_MM, TABLE_COARSE_MM);
            (f, gamma1_mm, gamma2_mm)
        })
        .collect();
    let (deepest, ..) = normal.last().ok_or_else(|| FemError::Invalid("an empty sweep".into()))?;
    let twists: Vec<f64> = plan.twists_deg.iter().map(|d| d.to_radians()).collect();
    let theta = fine.theta1_rad(deepest, &twists, plan.friction)?;
    let torsion_deg = plan.twists_deg.iter().zip(&theta).map(|(&d, t)| (d, t.to_degrees())).collect();
    let normal: Vec<LargeState> =
        normal.into_iter().map(|(f, gamma1_mm, gamma2_mm)| LargeState { gamma1_mm, gamma2_mm, ..f }).collect();
    let beta_reached = normal.last().map_or(0.0, |s| s.gamma2_mm / indenter_radius_mm);
    Ok(Sweep { normal, torsion_deg, beta_reached })
}

/// Whether `e` is where the reference stops following the contact (its
/// iteration does not settle, its tangent gives out, or an element turns
/// inside out), rather than a fault of the input.
fn ends_the_sweep(e: &FemError) -> bool {
    matches!(e, FemError::ContactNotSettled(_) | FemError::NotPositiveDefinite(_) | FemError::Inverted(_))
}
