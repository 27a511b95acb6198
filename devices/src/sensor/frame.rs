//! One frame of a marker-based tactile sensor (Tac3D-class): the reference
//! position of every marker on the elastomer and its 3-D displacement.
//! Units: mm. Axis convention follows Tac3D: z is the outward surface normal,
//! so pressing into the elastomer gives negative `dz`.

use serde::Serialize;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SensorFrame {
    /// Frame counter as the sensor numbers it (need not start at 0); gaps mean lost frames.
    pub index: u64,
    /// Sensor-side timestamp, s.
    pub t_s: f64,
    /// Reference (undeformed) marker positions, mm, one `[x, y, z]` per marker.
    /// (Tac3D itself sends current positions, reference + displacement; its
    /// codec converts both ways.)
    pub positions: Vec<[f64; 3]>,
    /// Marker displacements from the reference, mm, same order as `positions`.
    pub displacements: Vec<[f64; 3]>,
}

impl SensorFrame {
    pub fn marker_count(&self) -> usize {
        self.positions.len()
    }
}
