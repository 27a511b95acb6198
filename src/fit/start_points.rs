//! Where the fits of a recording start E1 and nu1 when the data offer no
//! better guess: typical elastomers, scaled by the indenter's modulus E2 (the
//! indenter is chosen a few times stiffer than the gel).

use sim::physics::Material;

/// The full fit's starts when the paper's answer is implausible or ends on a
/// bound; the first is also its start for an unusable start point.
pub fn typical_elastomers(indenter_e_mpa: f64) -> [Material; 4] {
    let e2 = indenter_e_mpa;
    [(e2 / 3.0, 0.4), (e2 / 3.0, 0.25), (e2, 0.45), (e2 / 10.0, 0.35)].map(|(e1_mpa, nu1)| Material { e1_mpa, nu1 })
}

/// The diagnosis' generic starts when neither fit gives a usable one: a ladder
/// of stiffnesses around E2 at a common nu1.
pub fn stiffness_ladder(indenter_e_mpa: f64) -> [Material; 4] {
    [0.3, 1.0, 0.1, 3.0].map(|f| Material { e1_mpa: f * indenter_e_mpa, nu1: 0.4 })
}
