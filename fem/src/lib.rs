//! easycalib's own finite-element reference (docs/physics.md, "Finite-element
//! reference"): axisymmetric, small-strain, linear elasticity of the sensor's gel
//! — a cylinder bonded to a rigid window, free on its side — and of the
//! calibration indenter — a hemisphere whose flat face is held by the platform —
//! in contact with Coulomb friction (or none). It checks the analytical layer model on geometry the
//! analysis cannot take (a finite gel, a finite hemisphere) and is checked in turn
//! against what it did not make (Hertz, Segedin, the layer solver).
//!
//! Bilinear quadrilaterals with selective reduced integration, a banded Cholesky
//! factor per body, each body condensed to its contact-surface compliance, and an
//! active set for the contact.
// Library code answers bad input with an error, never a panic: no unwrap or
// expect outside tests (ARCHITECTURE.md, "Conventions").
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]
// Matrix code reads as the algebra it implements: index loops on purpose.
#![allow(clippy::needless_range_loop)]

pub mod banded;
pub mod contact;
mod dense;
pub mod elastic;
pub mod forward;
pub mod hyper;
pub mod mesh;
mod quad;
pub mod tabulated;
pub mod torsion;

pub use contact::{ContactState, TwoBodyContact};

/// The cache behind `m`, locked. A cache only saves work, so one whose lock a
/// panicking thread poisoned (its contents possibly half-written) is emptied
/// and used again rather than refused: the answers are the same, rebuilt.
pub fn lock_cache<T: Default>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    match m.lock() {
        Ok(g) => g,
        Err(poisoned) => {
            let mut g = poisoned.into_inner();
            *g = T::default();
            m.clear_poison();
            g
        }
    }
}
pub use elastic::{Body, Integration, Material};
pub use mesh::{Base, Mesh};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FemError {
    #[error("invalid model: {0}")]
    Invalid(String),
    #[error("the stiffness matrix is not positive definite at equation {0} (a support is missing)")]
    NotPositiveDefinite(usize),
    #[error("the contact iteration did not settle in {0} passes")]
    ContactNotSettled(usize),
    /// A large-strain element turned inside out (the deformation beyond what
    /// its mesh can follow): the state before it is the deepest there is.
    #[error("an element of the {0} MPa body inverted")]
    Inverted(f64),
}
