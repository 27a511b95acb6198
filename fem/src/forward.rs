//! The FE reference as a forward model a fit can afford (docs/physics.md,
//! "Finite-element reference"): each body reduced once to its contact-surface
//! compliance — the indenter for its own E2, nu2, R2; the gel for unit modulus at
//! a few Poisson's ratios, interpolated in nu1 and scaled by 1/E1 — so one
//! parameter set costs a small dense contact problem per stage position.

use std::collections::{HashMap, VecDeque};
use std::f64::consts::PI;
use std::sync::{Arc, Mutex, OnceLock};

use crate::FemError;
use crate::contact::{ContactState, FrictionalContact, TwoBodyContact};
use crate::dense::{self, PrefixCholesky};
use crate::elastic::{Body, Integration, Material, SurfaceCompliance, combine_block};
use crate::mesh::{Base, Mesh};
use crate::tabulated::{LawAt, TabulatedLaw};
use crate::torsion::TorsionBody;

/// Element size at the contact, mm, and the gel's radius in thicknesses. A real
/// gel is a few thicknesses wide with a free rim, and the rim matters: at a/h
/// 0.8 a 40 mm wide 5 mm gel reads gamma1 0.3 % under a 30 mm one, several µm
/// at depth. Three thicknesses is the EasyCalib reference sensor's gel (30 mm
/// across, 5 mm thick; docs/physics.md, "Finite-element reference").
pub const FINE_MM: f64 = 0.06;
const GEL_RADIUS_IN_H: f64 = 3.0;
/// Poisson's ratios at which the gel is tabulated (Chebyshev points on [0, 0.5]).
const NU_NODES: usize = 9;

fn nu_nodes() -> Vec<f64> {
    (0..NU_NODES).map(|k| 0.25 - 0.25 * (PI * (k as f64 + 0.5) / NU_NODES as f64).cos()).collect()
}

/// Lagrange weights of the nu nodes at `nu`.
fn lagrange(nodes: &[f64], nu: f64) -> Vec<f64> {
    (0..nodes.len())
        .map(|k| (0..nodes.len()).filter(|&m| m != k).map(|m| (nu - nodes[m]) / (nodes[k] - nodes[m])).product())
        .collect()
}

/// The gel of one thickness, for unit modulus, at the tabulated Poisson's ratios,
/// on the surface nodes an indenter can touch.
struct GelTables {
    /// Surface radii of the tabulated nodes, mm.
    r: Vec<f64>,
    nu: Vec<f64>,
    /// Surface compliance in (r, z) per nu node (E1 = 1), column-major.
    normal: Vec<SurfaceCompliance>,
    /// Torsion compliance for unit shear modulus.
    torsion: Vec<Vec<f64>>,
}

/// The gel's mesh for a layer of thickness `h` (both references use it).
pub fn gel_mesh(h: f64) -> Result<Mesh, FemError> {
    gel_mesh_at(h, FINE_MM)
}

/// [`gel_mesh`]'s layout with elements of `fine_mm` at the contact (the
/// large-strain table's reference runs use a finer one than the layer
/// model: docs/physics.md, "Large strain").
pub fn gel_mesh_at(h: f64, fine_mm: f64) -> Result<Mesh, FemError> {
    Mesh::gel((GEL_RADIUS_IN_H * h).max(12.0), h, fine_mm, 6.0, 1.5)
}

/// Radial segments of the hemisphere's mesh against a gel with elements of
/// `fine_mm` at the contact (30 at the layer model's 0.06 mm; fewer at a
/// finer gel mesh invert an element under a deep press).
pub fn hemisphere_segments(fine_mm: f64) -> usize {
    (30.0 * FINE_MM / fine_mm).round().max(1.0) as usize
}

impl GelTables {
    /// The tables on the first `nodes` surface nodes; the nine Poisson's ratios
    /// are factored and solved on threads of their own.
    fn build(base: Base, h: f64, fine_mm: f64, nodes: usize, integration: Integration) -> Result<Self, FemError> {
        let mesh = gel_mesh_at(h, fine_mm)?.on_base(base);
        let nodes = nodes.min(mesh.surface.len());
        let r = mesh.surface_radii()[..nodes].to_vec();
        let nu = nu_nodes();
        let (torsion, normal) = std::thread::scope(|scope| {
            let per_nu: Vec<_> = nu
                .iter()
                .map(|&v| {
                    let mesh = mesh.clone();
                    scope.spawn(move || {
                        Body::with_integration(mesh, Material { e_mpa: 1.0, nu: v.min(0.4999) }, integration)
                            .map(|b| b.surface_compliance_rz(nodes))
                    })
                })
                .collect();
            let torsion = TorsionBody::new(&mesh).map(|t| t.surface_compliance(&mesh.surface[..nodes]));
            let normal: Result<Vec<_>, FemError> = per_nu
                .into_iter()
                .map(|h| h.join().unwrap_or_else(|_| Err(FemError::Invalid("a table thread panicked".into()))))
                .collect();
            (torsion, normal)
        });
        Ok(Self { r, nu, normal: normal?, torsion: torsion? })
    }

    /// Shared per thickness and node count: the tables take seconds and every
    /// fit of a gel reuses them.
    fn cached(base: Base, h: f64, fine_mm: f64, nodes: usize, integration: Integration) -> Result<Arc<Self>, FemError> {
        static CACHE: BuildOnce<(Base, [u64; 2], usize, Integration), GelTables> = BuildOnce::new();
        CACHE.get((base, [h.to_bits(), fine_mm.to_bits()], nodes, integration), || {
            Self::build(base, h, fine_mm, nodes, integration)
        })
    }
}

/// One value per key, built once per process: callers that ask for a key
/// while it is being built wait for that build instead of starting their own
/// (the fit's parallel friction paths all ask for the tables on first use).
/// A failed build is kept too (it fails the same way again).
struct BuildOnce<K, T> {
    cells: OnceLock<Mutex<HashMap<K, Arc<Built<T>>>>>,
}

/// A value of [`BuildOnce`], or how its build failed, once built.
type Built<T> = OnceLock<Result<Arc<T>, FemError>>;

impl<K: std::hash::Hash + Eq, T> BuildOnce<K, T> {
    const fn new() -> Self {
        Self { cells: OnceLock::new() }
    }

    fn get(&self, key: K, build: impl FnOnce() -> Result<T, FemError>) -> Result<Arc<T>, FemError> {
        let cells = self.cells.get_or_init(|| Mutex::new(HashMap::new()));
        let cell = {
            let mut map = crate::lock_cache(cells);
            map.entry(key).or_default().clone()
        };
        cell.get_or_init(|| build().map(Arc::new)).clone()
    }
}

/// The indenter (a hemisphere held at its flat face) against a bonded gel of one thickness.
pub struct Forward {
    /// What it was built from: the gel's base and thickness, the indenter's
    /// modulus, Poisson's ratio and radius, the element size at the contact
    /// and the element's integration (its tabulated law builds the same rig
    /// on a finer mesh too).
    base: Base,
    thickness_mm: f64,
    indenter_nu: f64,
    fine_mm: f64,
    integration: Integration,
    gel: Arc<GelTables>,
    n: usize,
    radius_mm: f64,
    indenter_e_mpa: f64,
    /// The frictionless law tabulated in its groups, built on first use.
    tabulated: OnceLock<Result<Arc<TabulatedLaw>, FemError>>,
    ind_normal: Arc<SurfaceCompliance>,
    ind_torsion: Vec<Vec<f64>>,
    /// The models of the last few parameter sets asked for (see [`Forward::model_shared`]).
    recent: Mutex<VecDeque<([u64; 2], Arc<Model>)>>,
    /// The tabulated law at the last few parameter sets asked for (see
    /// [`Forward::tabulated_at`]).
    recent_laws: Mutex<VecDeque<(LawKey, Arc<LawAt>)>>,
}

/// A contracted law's key: (E1, nu1) bit for bit, and the twist's disc.
type LawKey = ([u64; 2], TwistDisc);

/// How many parameter sets [`Forward::model_shared`] keeps: a fit's finite
/// differences in the contact offset and the friction come back to the
/// (E1, nu1) of the point they are taken about.
const RECENT_MODELS: usize = 8;

/// What the frictional contact of one parameter set is built from.
struct FrictionalParts {
    gel: Arc<GelTables>,
    weights: Vec<f64>,
    e1_mpa: f64,
    indenter: Arc<SurfaceCompliance>,
    radius_mm: f64,
}

/// The disc theta1 is taken over (docs/physics.md, "Finite-element
/// reference", theta1 as the sensor takes it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum TwistDisc {
    /// Out to the contact's radius ([`TwoBodyContact::contact_radius_mm`]):
    /// the sensor's r <= a. The default.
    #[default]
    Contact,
    /// Out to the interpolated edge of the nodes in contact
    /// ([`TwoBodyContact::contact_edge_mm`]), a third of a node spacing
    /// further: the linear side of the large-strain twist ratios was taken
    /// over it, and a ratio scales the twist it was taken against.
    NodeEdge,
}

/// What the twists of one normal state share: its outermost node in contact,
/// each node's Coulomb limit for the twist, the radius of the disc theta1 is
/// taken over, and the stuck cores its twists have solved so far.
#[derive(Debug)]
pub struct TwistSetup {
    last: usize,
    cap: Vec<f64>,
    disc_mm: f64,
    cores: Mutex<Cores>,
}

impl Clone for TwistSetup {
    fn clone(&self) -> Self {
        let cores = crate::lock_cache(&self.cores).clone();
        Self { last: self.last, cap: self.cap.clone(), disc_mm: self.disc_mm, cores: Mutex::new(cores) }
    }
}

/// One parameter set (E1, nu1) of the forward model.
pub struct Model {
    contact: TwoBodyContact,
    /// The frictional contact, built on first use (the fit's fast form needs
    /// only the normal block).
    frictional: OnceLock<FrictionalContact>,
    frictional_parts: FrictionalParts,
    /// The gel's torsion compliance for unit shear modulus (shared with
    /// every model of this gel) and 1/G1: the gel's own is their product,
    /// taken where it is needed rather than stored per model.
    torsion_unit: Arc<GelTables>,
    inv_g1: f64,
    torsion_sum: Vec<Vec<f64>>,
    /// Cholesky factor of `torsion_sum` off the axis (nodes 1..): the stuck core
    /// of a twisted contact, nodes 1..=m, at O(m²); factored as far as a
    /// stuck core has reached.
    torsion_factor: Mutex<PrefixCholesky>,
    /// Frictionless states solved through [`Model::normal_memo`], by approach.
    solved: Mutex<HashMap<u64, ContactState>>,
    /// The last frictional paths followed through [`Model::normal_path_memo`].
    paths: Mutex<VecDeque<(PathKey, Arc<Vec<ContactState>>)>>,
}

/// What a frictional path was asked: the approaches, the friction and the
/// load step, bit for bit.
#[derive(PartialEq)]
struct PathKey {
    deltas: Vec<u64>,
    mu: u64,
    step: u64,
}

/// How many states [`Model::normal_memo`] keeps before it starts afresh, and
/// how many paths [`Model::normal_path_memo`] keeps.
const MEMO_STATES: usize = 4096;
const MEMO_PATHS: usize = 2;

impl Forward {
    /// Shared per (thickness, indenter) on a bonded gel: built once per process.
    pub fn cached(
        thickness_mm: f64,
        indenter_e_mpa: f64,
        indenter_nu: f64,
        indenter_r_mm: f64,
    ) -> Result<Arc<Self>, FemError> {
        Self::cached_on(Base::Bonded, thickness_mm, indenter_e_mpa, indenter_nu, indenter_r_mm)
    }

    /// [`Self::cached`] on a gel sitting on its window as `base` says.
    pub fn cached_on(
        base: Base,
        thickness_mm: f64,
        indenter_e_mpa: f64,
        indenter_nu: f64,
        indenter_r_mm: f64,
    ) -> Result<Arc<Self>, FemError> {
        static CACHE: BuildOnce<(Base, [u64; 4]), Forward> = BuildOnce::new();
        let key = (base, [thickness_mm, indenter_e_mpa, indenter_nu, indenter_r_mm].map(f64::to_bits));
        CACHE.get(key, || {
            Self::build(base, thickness_mm, indenter_e_mpa, indenter_nu, indenter_r_mm, FINE_MM, Integration::Selective)
        })
    }

    /// This rig on a mesh of `fine_mm` elements at the contact, shared per
    /// process like [`Self::cached_on`] (the tabulated law's second mesh).
    pub fn cached_on_mesh(&self, fine_mm: f64) -> Result<Arc<Self>, FemError> {
        static CACHE: BuildOnce<(Base, [u64; 5], Integration), Forward> = BuildOnce::new();
        let (base, integration) = (self.base, self.integration);
        let dims = [self.thickness_mm, self.indenter_e_mpa, self.indenter_nu, self.radius_mm, fine_mm];
        CACHE.get((base, dims.map(f64::to_bits), integration), || {
            let [h, e2, nu2, r2, fine] = dims;
            Self::build(base, h, e2, nu2, r2, fine, integration)
        })
    }

    /// The element size at the contact, mm.
    pub fn element_mm(&self) -> f64 {
        self.fine_mm
    }

    pub fn new(thickness_mm: f64, indenter_e_mpa: f64, indenter_nu: f64, indenter_r_mm: f64) -> Result<Self, FemError> {
        Self::with_integration(thickness_mm, indenter_e_mpa, indenter_nu, indenter_r_mm, Integration::Selective)
    }

    /// [`Self::new`] on elements that integrate their volumetric part as
    /// `integration` says (the large-strain tables' examples build the linear
    /// side of their ratios on the neo-Hookean reference's own element).
    pub fn with_integration(
        thickness_mm: f64,
        indenter_e_mpa: f64,
        indenter_nu: f64,
        indenter_r_mm: f64,
        integration: Integration,
    ) -> Result<Self, FemError> {
        Self::build(Base::Bonded, thickness_mm, indenter_e_mpa, indenter_nu, indenter_r_mm, FINE_MM, integration)
    }

    fn build(
        base: Base,
        thickness_mm: f64,
        indenter_e_mpa: f64,
        indenter_nu: f64,
        indenter_r_mm: f64,
        fine_mm: f64,
        integration: Integration,
    ) -> Result<Self, FemError> {
        if !(thickness_mm > 0.0 && thickness_mm.is_finite() && indenter_r_mm > 0.0 && indenter_r_mm < 100.0) {
            return Err(FemError::Invalid(format!("layer {thickness_mm} mm, indenter radius {indenter_r_mm} mm")));
        }
        // Only the gel's nodes under the indenter can touch it: tabulate those.
        let rs: Vec<f64> = gel_mesh_at(thickness_mm, fine_mm)?
            .surface_radii()
            .into_iter()
            .filter(|&r| r < 0.97 * indenter_r_mm)
            .collect();
        let gel = GelTables::cached(base, thickness_mm, fine_mm, rs.len(), integration)?;
        let hemi = Mesh::hemisphere(indenter_r_mm, &rs, hemisphere_segments(fine_mm))?;
        let g2 = indenter_e_mpa / (2.0 * (1.0 + indenter_nu));
        let ind_torsion = TorsionBody::new(&hemi)?
            .surface_compliance(&hemi.surface)
            .into_iter()
            .map(|c| c.into_iter().map(|v| v / g2).collect())
            .collect();
        let ind_normal = Arc::new(
            Body::with_integration(hemi, Material { e_mpa: indenter_e_mpa, nu: indenter_nu }, integration)?
                .surface_compliance_rz(usize::MAX),
        );
        Ok(Self {
            base,
            thickness_mm,
            indenter_nu,
            fine_mm,
            integration,
            gel,
            n: rs.len(),
            radius_mm: indenter_r_mm,
            indenter_e_mpa,
            tabulated: OnceLock::new(),
            ind_normal,
            ind_torsion,
            recent: Mutex::new(VecDeque::with_capacity(RECENT_MODELS)),
            recent_laws: Mutex::new(VecDeque::with_capacity(RECENT_MODELS)),
        })
    }

    /// The indenter's Young's modulus, MPa.
    pub fn indenter_e_mpa(&self) -> f64 {
        self.indenter_e_mpa
    }

    /// The indenter's radius, mm.
    pub fn indenter_radius_mm(&self) -> f64 {
        self.radius_mm
    }

    /// The gel's surface nodes the indenter can touch.
    pub fn surface_nodes(&self) -> usize {
        self.n
    }

    /// This rig's frictionless law tabulated in its dimensionless groups
    /// ([`TabulatedLaw`]), built on first use and kept with the model.
    pub fn tabulated(&self) -> Result<Arc<TabulatedLaw>, FemError> {
        self.tabulated.get_or_init(|| TabulatedLaw::build(self).map(Arc::new)).clone()
    }

    /// [`TabulatedLaw::at`] on this rig's table, shared with the last few
    /// callers that asked for the same (E1, nu1) (bit for bit): a fit's
    /// finite differences in the contact offset and the friction read the
    /// law at the (E1, nu1) of the point they are taken about, and the
    /// contraction of the material axes is most of a tabulated evaluation.
    /// `None` where the table cannot be built or does not reach.
    pub fn tabulated_at(&self, e1_mpa: f64, nu1: f64) -> Option<Arc<LawAt>> {
        self.tabulated_over(e1_mpa, nu1, TwistDisc::Contact)
    }

    /// [`Forward::tabulated_at`] with theta1 taken over `disc`.
    pub fn tabulated_over(&self, e1_mpa: f64, nu1: f64, disc: TwistDisc) -> Option<Arc<LawAt>> {
        let key = ([e1_mpa.to_bits(), nu1.to_bits()], disc);
        if let Some(at) = crate::lock_cache(&self.recent_laws).iter().find(|(k, _)| *k == key).map(|(_, a)| a.clone()) {
            return Some(at);
        }
        let at = Arc::new(self.tabulated().ok()?.at_over(e1_mpa, nu1, disc)?);
        let mut r = crate::lock_cache(&self.recent_laws);
        if r.len() == RECENT_MODELS {
            r.pop_front();
        }
        r.push_back((key, at.clone()));
        Some(at)
    }

    /// [`Forward::model`], shared with the last few callers that asked for
    /// the same (E1, nu1) (bit for bit): a model's answers do not depend on
    /// what it solved before, so a fit that varies only the contact offset or
    /// the friction about a point builds the model (its interpolated
    /// compliances and their factors) once.
    pub fn model_shared(&self, e1_mpa: f64, nu1: f64) -> Arc<Model> {
        let key = [e1_mpa.to_bits(), nu1.to_bits()];
        if let Some(m) = crate::lock_cache(&self.recent).iter().find(|(k, _)| *k == key).map(|(_, m)| m.clone()) {
            return m;
        }
        let m = Arc::new(self.model(e1_mpa, nu1));
        let mut r = crate::lock_cache(&self.recent);
        if r.len() == RECENT_MODELS {
            r.pop_front();
        }
        r.push_back((key, m.clone()));
        m
    }

    /// The model at elastomer modulus `e1_mpa` and Poisson's ratio `nu1` (0..0.5).
    pub fn model(&self, e1_mpa: f64, nu1: f64) -> Model {
        let n = self.n;
        let w = lagrange(&self.gel.nu, nu1.clamp(0.0, 0.5));
        let zz: Vec<(f64, &Vec<Vec<f64>>)> = w.iter().copied().zip(self.gel.normal.iter().map(|m| &m.zz)).collect();
        let gel_zz = combine_block(&zz, n, e1_mpa);
        let inv_g1 = 2.0 * (1.0 + nu1) / e1_mpa;
        let torsion_sum: Vec<Vec<f64>> = self.gel.torsion[..n]
            .iter()
            .zip(&self.ind_torsion)
            .map(|(gel, ind)| gel[..n].iter().zip(&ind[..n]).map(|(g, i)| g * inv_g1 + i).collect())
            .collect();
        let torsion_factor = Mutex::new(PrefixCholesky::empty());
        let contact =
            TwoBodyContact::from_compliances(self.gel.r[..n].to_vec(), gel_zz, &self.ind_normal.zz, self.radius_mm);
        let frictional_parts = FrictionalParts {
            gel: self.gel.clone(),
            weights: w,
            e1_mpa,
            indenter: self.ind_normal.clone(),
            radius_mm: self.radius_mm,
        };
        Model {
            contact,
            frictional: OnceLock::new(),
            frictional_parts,
            torsion_unit: self.gel.clone(),
            inv_g1,
            torsion_sum,
            torsion_factor,
            solved: Mutex::new(HashMap::new()),
            paths: Mutex::new(VecDeque::with_capacity(MEMO_PATHS)),
        }
    }
}

impl Model {
    fn frictional(&self) -> &FrictionalContact {
        self.frictional.get_or_init(|| {
            let f = &self.frictional_parts;
            let n = self.contact.radii().len();
            let parts: Vec<(f64, &SurfaceCompliance)> = f.weights.iter().copied().zip(&f.gel.normal).collect();
            let gel = SurfaceCompliance::combine(&parts, n, f.e1_mpa);
            FrictionalContact::new(self.contact.radii().to_vec(), gel, &f.indenter, f.radius_mm)
        })
    }

    /// The radius of the contact of `st`, mm
    /// ([`TwoBodyContact::contact_radius_mm`]): the edge less the lead a
    /// node-to-node contact has on it.
    pub fn contact_radius_mm(&self, st: &ContactState) -> f64 {
        self.contact.contact_radius_mm(st)
    }

    /// The normal contact at platform approach `delta_mm`.
    pub fn normal(&self, delta_mm: f64) -> Result<ContactState, FemError> {
        self.contact.solve(delta_mm)
    }

    /// [`Model::normal`], remembered: a fit asks one model for the same
    /// approaches again (a finite difference in the friction moves no depth,
    /// and the fit's closing predictions repeat its last evaluation). The same
    /// state as [`Model::normal`] gives (it depends on nothing else).
    pub fn normal_memo(&self, delta_mm: f64) -> Result<ContactState, FemError> {
        let key = delta_mm.to_bits();
        if let Some(st) = crate::lock_cache(&self.solved).get(&key).cloned() {
            return Ok(st);
        }
        let st = self.contact.solve(delta_mm)?;
        let mut m = crate::lock_cache(&self.solved);
        if m.len() >= MEMO_STATES {
            m.clear();
        }
        m.insert(key, st.clone());
        Ok(st)
    }

    /// [`Model::normal_path`], remembering the last few paths asked of this
    /// model (bit for bit the same arguments give the same states).
    pub fn normal_path_memo(
        &self,
        deltas_mm: &[f64],
        mu: f64,
        max_step_mm: f64,
    ) -> Result<Arc<Vec<ContactState>>, FemError> {
        let key = PathKey {
            deltas: deltas_mm.iter().map(|d| d.to_bits()).collect(),
            mu: mu.to_bits(),
            step: max_step_mm.to_bits(),
        };
        if let Some(p) = crate::lock_cache(&self.paths).iter().find(|(k, _)| *k == key).map(|(_, p)| p.clone()) {
            return Ok(p);
        }
        let path = Arc::new(self.normal_path(deltas_mm, mu, max_step_mm)?);
        let mut q = crate::lock_cache(&self.paths);
        if q.len() == MEMO_PATHS {
            q.pop_front();
        }
        q.push_back((key, path.clone()));
        Ok(path)
    }

    /// The normal contact with Coulomb friction `mu` between the bodies, followed
    /// along a monotone approach through every entry of `deltas_mm` (a state per
    /// entry), in load steps of at most `max_step_mm`.
    pub fn normal_path(&self, deltas_mm: &[f64], mu: f64, max_step_mm: f64) -> Result<Vec<ContactState>, FemError> {
        self.frictional().solve_path(deltas_mm, mu, max_step_mm)
    }

    /// theta1 for a mount twist `twist_rad` (monotone from 0) at normal state `st`:
    /// the contact sticks where the tangential traction is inside Coulomb's cone,
    /// |(τ_r, τ_θ)| < mu p, and slips on it beyond, the radial part τ_r being the
    /// press's friction (`mu = inf` sticks everywhere). theta1 is the
    /// area-weighted least-squares twist of the gel's surface over the contact
    /// (see [`contact_twist`]).
    pub fn theta1_rad(&self, st: &ContactState, twist_rad: f64, mu: f64) -> Option<f64> {
        self.theta1_rad_at(&self.twist_setup(st, mu)?, twist_rad)
    }

    /// What every twist of normal state `st` with friction `mu` shares (see
    /// [`Model::theta1_rad_at`]), theta1 taken over the contact
    /// ([`TwistDisc::Contact`]); `None` when nothing is in contact off the axis.
    pub fn twist_setup(&self, st: &ContactState, mu: f64) -> Option<TwistSetup> {
        self.twist_setup_over(st, mu, TwistDisc::Contact)
    }

    /// [`Model::twist_setup`] with theta1 taken over `disc`.
    pub fn twist_setup_over(&self, st: &ContactState, mu: f64, disc: TwistDisc) -> Option<TwistSetup> {
        let r = self.contact.radii();
        let last = (0..r.len()).rev().find(|&i| st.nodal_force[i] > 0.0)?;
        if last == 0 {
            return None;
        }
        // Coulomb bounds the whole tangential traction: a node already carrying
        // radial friction from the press has only the rest of its cone left for
        // the twist (docs/physics.md, "Finite-element reference").
        let cap: Vec<f64> = (1..=last)
            .map(|i| {
                if mu.is_infinite() {
                    return f64::INFINITY;
                }
                let radial = st.nodal_shear.get(i).copied().unwrap_or(0.0);
                ((mu * st.nodal_force[i]).powi(2) - radial * radial).max(0.0).sqrt()
            })
            .collect();
        let disc_mm = match disc {
            TwistDisc::Contact => self.contact.contact_radius_mm(st),
            TwistDisc::NodeEdge => self.contact.contact_edge_mm(st),
        };
        Some(TwistSetup { last, cap, disc_mm, cores: Mutex::default() })
    }

    /// [`Model::theta1_rad`] for a mount twist `twist_rad` on a state prepared
    /// by [`Model::twist_setup`] (a torsion sweep twists one state many times).
    pub fn theta1_rad_at(&self, setup: &TwistSetup, twist_rad: f64) -> Option<f64> {
        let mut cores = crate::lock_cache(&setup.cores);
        self.twist_from(setup, twist_rad, &mut Vec::new(), &mut cores)
    }

    /// [`Model::theta1_rad_at`] at each of `twists_rad` (each loaded from
    /// zero, as there), solved in increasing order: a twist's slip annulus
    /// holds every node that slips at a smaller twist, so each search for it
    /// starts from the last one's instead of from a stuck contact (the same
    /// annulus, found in fewer rounds: the rounds only ever add nodes that
    /// are past their limit); and a stuck core met by an earlier twist is
    /// not solved again (the setup keeps them for every later twist of it).
    pub fn theta1_rad_sweep(&self, setup: &TwistSetup, twists_rad: &[f64]) -> Vec<Option<f64>> {
        let mut order: Vec<usize> = (0..twists_rad.len()).collect();
        order.sort_by(|&a, &b| twists_rad[a].total_cmp(&twists_rad[b]));
        let mut out = vec![None; twists_rad.len()];
        let mut slip = Vec::new();
        let mut cores = crate::lock_cache(&setup.cores);
        for k in order {
            out[k] = self.twist_from(setup, twists_rad[k], &mut slip, &mut cores);
        }
        out
    }

    /// The stuck core of `k` nodes (1..=k) with every node outside it slipping
    /// at its limit: its tractions per radian of twist and those the slipping
    /// annulus takes off them ([`Cores`]), solved on the factor's leading
    /// block; `None` when the factor does not reach that far.
    fn core<'c>(&self, setup: &TwistSetup, k: usize, cores: &'c mut Cores) -> Option<&'c (Vec<f64>, Vec<f64>)> {
        let m = setup.last;
        if cores.by_size.len() != m + 1 {
            cores.by_size = vec![None; m + 1];
            cores.forward_r.clear();
        }
        if cores.by_size[k].is_none() {
            let r = self.contact.radii();
            let mut f = crate::lock_cache(&self.torsion_factor);
            if f.extend_to(k, |i, j| self.torsion_sum[j + 1][i + 1]) < k {
                return None;
            }
            // L⁻¹ r is shared by every core (a forward substitution's
            // leading entries are those of any longer one).
            f.forward_extend(&mut cores.forward_r, k, |i| r[i + 1]);
            let per_rad = f.backward(cores.forward_r[..k].to_vec())?;
            // The annulus's load on the core, column by column (in the same
            // order per node as a row-wise sum).
            let mut by_slip = vec![0.0; k];
            for l in k..m {
                let col = &self.torsion_sum[l + 1];
                by_slip.iter_mut().zip(&col[1..=k]).for_each(|(v, g)| *v += g * setup.cap[l]);
            }
            let taken = f.solve_prefix(&by_slip)?;
            cores.by_size[k] = Some((per_rad, taken));
        }
        cores.by_size[k].as_ref()
    }

    /// theta1 at `twist_rad`, the slip annulus searched from `slip` (the nodes
    /// 1..=last known to slip; empty: none) and left there.
    fn twist_from(&self, setup: &TwistSetup, twist_rad: f64, slip: &mut Vec<bool>, cores: &mut Cores) -> Option<f64> {
        let r = self.contact.radii();
        let (last, cap) = (setup.last, &setup.cap);
        // Node 0 is on the axis (no twist displacement); unknowns are nodes
        // 1..=last, at index node - 1.
        let n = last;
        slip.resize(n, false);
        let mut t = vec![0.0; n];
        for _ in 0..=n {
            // The stuck nodes are the core out to the slip annulus: the
            // factor's leading block, solved once per core size; any other
            // set by elimination.
            let k = slip.iter().position(|&s| s).unwrap_or(n);
            let annulus = slip[k..].iter().all(|&s| s);
            let core = match annulus {
                true => self.core(setup, k, cores),
                false => None,
            };
            match core {
                Some((per_rad, taken)) => {
                    for (i, v) in t.iter_mut().enumerate() {
                        *v = if i < k { twist_rad * per_rad[i] - taken[i] } else { cap[i] };
                    }
                }
                None => {
                    let stick: Vec<usize> = (0..n).filter(|&i| !slip[i]).collect();
                    // Stuck nodes: Σ_stick G T + Σ_slip G cap = θ r.
                    let a: Vec<Vec<f64>> = stick
                        .iter()
                        .map(|&i| stick.iter().map(|&l| self.torsion_sum[l + 1][i + 1]).collect())
                        .collect();
                    let mut by_slip = vec![0.0; n];
                    for l in (0..n).filter(|&l| slip[l]) {
                        let col = &self.torsion_sum[l + 1];
                        by_slip.iter_mut().zip(&col[1..=n]).for_each(|(v, g)| *v += g * cap[l]);
                    }
                    let b: Vec<f64> = stick.iter().map(|&i| twist_rad * r[i + 1] - by_slip[i]).collect();
                    let x = if stick.is_empty() { Vec::new() } else { dense::solve(a, b)? };
                    for (i, v) in t.iter_mut().enumerate() {
                        *v = if slip[i] { cap[i] } else { 0.0 };
                    }
                    for (m, &i) in stick.iter().enumerate() {
                        t[i] = x[m];
                    }
                }
            }
            // Stuck nodes past the friction limit slip (the slip annulus grows inward).
            let mut grew = false;
            for i in 0..n {
                if !slip[i] && t[i] > cap[i] {
                    slip[i] = true;
                    grew = true;
                }
            }
            if !grew {
                break;
            }
        }
        // The gel's twist displacement at every node out to the first one
        // outside the contact (its surface moves there too).
        let outer = (last + 1).min(r.len() - 1);
        // Column by column (contiguous); the axis node does not turn.
        let mut u = vec![0.0; outer + 1];
        for (i, ti) in t.iter().enumerate() {
            let f = ti * self.inv_g1;
            u[1..].iter_mut().zip(&self.torsion_unit.torsion[i + 1][1..=outer]).for_each(|(ui, g)| *ui += g * f);
        }
        contact_twist(&r[..=outer], &u, setup.disc_mm)
    }
}

/// A twist setup's stuck cores, by size k: with nodes 1..=k stuck and every
/// node outside slipping at its Coulomb limit, the core's tractions are linear
/// in the twist θ — θ times the first vector less the second (the slipping
/// annulus's load on the core, carried by the core) — so a sweep whose twists
/// meet the same annulus solves it once (docs/physics.md, "Finite-element
/// reference").
#[derive(Debug, Clone, Default)]
struct Cores {
    by_size: Vec<Option<(Vec<f64>, Vec<f64>)>>,
    /// L⁻¹ r over the nodes off the axis, as far as a core has needed it.
    forward_r: Vec<f64>,
}

/// theta1 as the sensor takes it: the least-squares twist of the surface's
/// twist displacement `u` (at radii `r`, linear between them) over the disc of
/// radius `edge_mm`, area-weighted: ∫ u r² dr / ∫ r³ dr over [0, edge].
fn contact_twist(r: &[f64], u: &[f64], edge_mm: f64) -> Option<f64> {
    // Three-point Gauss–Legendre on each piece: exact for u r² with u linear.
    const X: [f64; 3] = [-0.774_596_669_241_483_4, 0.0, 0.774_596_669_241_483_4];
    const W: [f64; 3] = [5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0];
    let mut num = 0.0;
    for k in 0..r.len().saturating_sub(1) {
        let (a, b) = (r[k], r[k + 1].min(edge_mm));
        if b <= a {
            break;
        }
        let slope = (u[k + 1] - u[k]) / (r[k + 1] - r[k]);
        let (mid, half) = (0.5 * (a + b), 0.5 * (b - a));
        for (x, w) in X.iter().zip(W) {
            let rr = mid + half * x;
            num += w * half * (u[k] + slope * (rr - r[k])) * rr * rr;
        }
    }
    let den = edge_mm.powi(4) / 4.0;
    (den > 0.0).then_some(num / den)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// theta1 by the plain stick/slip iteration: every round eliminates the
    /// whole stuck set with the slipping nodes' loads on its right-hand side,
    /// nothing kept between rounds or twists.
    fn twist_by_elimination(m: &Model, setup: &TwistSetup, twist_rad: f64) -> Option<f64> {
        let r = m.contact.radii();
        let n = setup.last;
        let (mut slip, mut t) = (vec![false; n], vec![0.0; n]);
        for _ in 0..=n {
            let stick: Vec<usize> = (0..n).filter(|&i| !slip[i]).collect();
            let a = stick.iter().map(|&i| stick.iter().map(|&l| m.torsion_sum[l + 1][i + 1]).collect()).collect();
            let b = stick
                .iter()
                .map(|&i| {
                    let by_slip: f64 =
                        (0..n).filter(|&l| slip[l]).map(|l| m.torsion_sum[l + 1][i + 1] * setup.cap[l]).sum();
                    twist_rad * r[i + 1] - by_slip
                })
                .collect();
            let x = if stick.is_empty() { Vec::new() } else { dense::solve(a, b)? };
            for (i, v) in t.iter_mut().enumerate() {
                *v = if slip[i] { setup.cap[i] } else { 0.0 };
            }
            for (k, &i) in stick.iter().enumerate() {
                t[i] = x[k];
            }
            let over: Vec<usize> = (0..n).filter(|&i| !slip[i] && t[i] > setup.cap[i]).collect();
            if over.is_empty() {
                break;
            }
            over.iter().for_each(|&i| slip[i] = true);
        }
        let outer = (n + 1).min(r.len() - 1);
        let mut u = vec![0.0; outer + 1];
        for (i, ti) in t.iter().enumerate() {
            for (k, g) in m.torsion_unit.torsion[i + 1][1..=outer].iter().enumerate() {
                u[k + 1] += g * ti * m.inv_g1;
            }
        }
        contact_twist(&r[..=outer], &u, setup.disc_mm)
    }

    /// The stuck cores a twist set-up keeps (each core's answer per radian
    /// and the slipping annulus's load it carries, solved once per core size
    /// on the factor's leading block) give the twist the plain iteration gives,
    /// for twists taken in a sweep, alone after it, and out into slip: the
    /// largest twist's theta1 per degree falls by more than a tenth from the
    /// smallest's, or the annulus would never have been met.
    #[test]
    fn a_twists_kept_cores_solve_as_elimination_does() {
        let model = Forward::cached(5.0, 2.0, 0.4, 5.0).unwrap().model(1.0, 0.48);
        let st = model.normal(1.5).unwrap();
        let setup = model.twist_setup(&st, 0.4).unwrap();
        let twists: Vec<f64> =
            [8.0, 0.5, 3.0, 12.0, 0.5, 20.0, 1.0, 6.0].iter().map(|d: &f64| d.to_radians()).collect();
        let swept = model.theta1_rad_sweep(&setup, &twists);
        let mut per_rad = Vec::new();
        for (&t, s) in twists.iter().zip(&swept) {
            let plain = twist_by_elimination(&model, &model.twist_setup(&st, 0.4).unwrap(), t).unwrap();
            let alone = model.theta1_rad_at(&setup, t).unwrap();
            let s = s.unwrap();
            for v in [s, alone] {
                assert!((v - plain).abs() <= 1e-10 * plain.abs(), "twist {t}: kept cores {v}, elimination {plain}");
            }
            per_rad.push((t, plain / t));
        }
        per_rad.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (first, last) = (per_rad[0].1, per_rad[per_rad.len() - 1].1);
        assert!(last < 0.9 * first, "no slip reached: theta1 per radian {first} at the smallest twist, {last} at 20°");
    }

    /// A thread that panics while holding a twist set-up's core cache (or the
    /// model's torsion factor) poisons its lock; the next twists must still
    /// answer, and answer as an untouched set-up does — not return nothing,
    /// which a fit would read as no twist at all.
    #[test]
    fn a_poisoned_cache_is_rebuilt_not_refused() {
        let model = Forward::cached(5.0, 2.0, 0.4, 5.0).unwrap().model(1.0, 0.48);
        let st = model.normal(1.5).unwrap();
        let setup = model.twist_setup(&st, 0.4).unwrap();
        let twists: Vec<f64> = [0.5, 4.0, 15.0].iter().map(|d: &f64| d.to_radians()).collect();
        let clean: Vec<f64> = model.theta1_rad_sweep(&setup, &twists).into_iter().map(Option::unwrap).collect();
        std::thread::scope(|s| {
            let poison = s.spawn(|| {
                let _cores = setup.cores.lock().unwrap();
                let _factor = model.torsion_factor.lock().unwrap();
                panic!("a panic while the caches are held");
            });
            assert!(poison.join().is_err());
        });
        assert!(setup.cores.is_poisoned() && model.torsion_factor.is_poisoned());
        for (&t, &c) in twists.iter().zip(&clean) {
            let again = model.theta1_rad_at(&setup, t);
            assert!(
                again.is_some_and(|v| (v - c).abs() <= 1e-12 * c.abs()),
                "twist {t}: {again:?} after the panic, {c} before"
            );
        }
        assert!(!setup.cores.is_poisoned() && !model.torsion_factor.is_poisoned());
        let swept = model.theta1_rad_sweep(&setup.clone(), &twists);
        assert_eq!(swept.iter().filter(|v| v.is_some()).count(), twists.len());
    }
}
