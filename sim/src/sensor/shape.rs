//! A declared gel layer's normal surface field, as a departure from Hertz's
//! (docs/sensing.md, "On a layer"). A layer bonded to its window is stiffer
//! than a half-space where the contact is wide against its thickness: outside
//! the contact its surface falls off faster than Hertz's field, and inside it
//! the surface follows the indenter rather than Hertz's paraboloid of radius
//! sqrt(gamma1 / curvature). The field is written
//!
//! w(r) = gamma1 (hertz(r / a) + D(r; a)) - sag(r; a),
//!
//! with hertz the half-space shape ([`super::field::normal_shape`]), sag the
//! spheres' sag below their paraboloids ([`super::field::spheres_sag_mm`]) and
//! D the layer's departure, tabulated here at a set of contact radii from a
//! model of the layer (the project's FE layer, built in the controller crate).
//! On a half-space D is zero; it grows about in proportion to a / h.

/// The departure D(r; a) of a layer's normal surface field from Hertz's,
/// tabulated at contact radii `radii_mm` on surface radii 0, `step_mm`, ...
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceShape {
    radii_mm: Vec<f64>,
    step_mm: f64,
    /// Per tabulated contact radius, D at r = j `step_mm`.
    departure: Vec<Vec<f64>>,
}

impl SurfaceShape {
    /// A table of `departure[k][j]` = D(j `step_mm`; `radii_mm[k]`). The
    /// contact radii must be positive and increasing, every row as long and
    /// at least two long, and every value finite.
    pub fn new(radii_mm: Vec<f64>, step_mm: f64, departure: Vec<Vec<f64>>) -> Result<Self, String> {
        let len = departure.first().map_or(0, Vec::len);
        if radii_mm.is_empty() || radii_mm.len() != departure.len() {
            return Err(format!("{} contact radii for {} rows", radii_mm.len(), departure.len()));
        }
        if !(step_mm > 0.0 && step_mm.is_finite()) || len < 2 {
            return Err(format!("surface radii every {step_mm} mm, {len} of them"));
        }
        if radii_mm[0] <= 0.0 || radii_mm.windows(2).any(|w| w[1] <= w[0]) || !radii_mm.iter().all(|a| a.is_finite()) {
            return Err("contact radii must be positive, finite and increasing".into());
        }
        if departure.iter().any(|row| row.len() != len || !row.iter().all(|v| v.is_finite())) {
            return Err("rows of unequal length or with non-finite values".into());
        }
        Ok(Self { radii_mm, step_mm, departure })
    }

    /// The tabulated contact radii, mm.
    pub fn radii_mm(&self) -> &[f64] {
        &self.radii_mm
    }

    /// The table (1 - `s`) self + `s` `other`, entry by entry (`s` outside
    /// 0..1 extrapolates); `None` unless both tables are on the same radii.
    pub fn mix(&self, other: &Self, s: f64) -> Option<Self> {
        let same = self.radii_mm == other.radii_mm
            && self.step_mm == other.step_mm
            && self.departure.iter().zip(&other.departure).all(|(a, b)| a.len() == b.len());
        (same && s.is_finite()).then(|| Self {
            radii_mm: self.radii_mm.clone(),
            step_mm: self.step_mm,
            departure: self
                .departure
                .iter()
                .zip(&other.departure)
                .map(|(a, b)| a.iter().zip(b).map(|(x, y)| x + s * (y - x)).collect())
                .collect(),
        })
    }

    /// Row `k` at surface radius `r_mm`: linear between the tabulated radii,
    /// held beyond the last.
    fn row(&self, k: usize, r_mm: f64) -> f64 {
        let row = &self.departure[k];
        let x = (r_mm / self.step_mm).clamp(0.0, (row.len() - 1) as f64);
        let j = (x.floor() as usize).min(row.len() - 2);
        let t = x - j as f64;
        row[j] * (1.0 - t) + row[j + 1] * t
    }

    /// D(r; a): the departure at `r_mm` from the centre of a contact of
    /// radius `a_mm`, interpolated between the tabulated contacts at the same
    /// r / a. Below the smallest tabulated contact it shrinks in proportion
    /// to a (the half-space limit); beyond the largest it is held. 0 for a
    /// contact radius that is not positive and finite.
    pub fn departure(&self, r_mm: f64, a_mm: f64) -> f64 {
        if !(a_mm > 0.0 && a_mm.is_finite()) || r_mm.is_nan() {
            return 0.0;
        }
        let rho = r_mm.abs() / a_mm;
        let radii = &self.radii_mm;
        let last = radii.len() - 1;
        if a_mm <= radii[0] {
            return self.row(0, rho * radii[0]) * a_mm / radii[0];
        }
        if a_mm >= radii[last] {
            return self.row(last, rho * radii[last]);
        }
        let k = radii.partition_point(|&x| x <= a_mm).clamp(1, last) - 1;
        let t = (a_mm - radii[k]) / (radii[k + 1] - radii[k]);
        self.row(k, rho * radii[k]) * (1.0 - t) + self.row(k + 1, rho * radii[k + 1]) * t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table() -> SurfaceShape {
        // D = -0.1 a (r / (r + 1)) at a = 1 and 2, every 0.5 mm to 10 mm.
        let radii = vec![1.0, 2.0];
        let rows =
            radii.iter().map(|a| (0..=20).map(|j| -0.1 * a * (0.5 * j as f64) / (0.5 * j as f64 + 1.0)).collect());
        let rows = rows.collect();
        SurfaceShape::new(radii, 0.5, rows).unwrap()
    }

    #[test]
    fn the_departure_is_read_at_the_same_r_over_a_between_contacts() {
        let s = table();
        // On a tabulated row, at a tabulated radius: the value itself.
        assert!((s.departure(1.5, 1.0) - (-0.1 * 1.5 / 2.5)).abs() < 1e-15);
        // Halfway between the rows, at rho = 1: the mean of the rows at r = 1 and 2.
        let want = 0.5 * (-0.1 * 1.0 / 2.0) + 0.5 * (-0.2 * 2.0 / 3.0);
        assert!((s.departure(1.5, 1.5) - want).abs() < 1e-15);
        // Below the first row it shrinks with a; beyond the table it holds.
        assert!((s.departure(0.5, 0.5) - 0.5 * s.departure(1.0, 1.0)).abs() < 1e-15);
        assert_eq!(s.departure(100.0, 2.0), s.departure(10.0, 2.0));
        assert_eq!(s.departure(1.0, 0.0), 0.0);
        assert_eq!(s.departure(1.0, f64::NAN), 0.0);
    }

    #[test]
    fn two_tables_mix_entry_by_entry() {
        let (a, b) = (table(), SurfaceShape::new(vec![1.0, 2.0], 0.5, vec![vec![1.0; 21]; 2]).unwrap());
        let m = a.mix(&b, 0.25).unwrap();
        for (r, c) in [(0.3, 1.0), (2.7, 1.6), (7.0, 3.0)] {
            assert!((m.departure(r, c) - (0.75 * a.departure(r, c) + 0.25)).abs() < 1e-14);
        }
        assert!(a.mix(&SurfaceShape::new(vec![1.0, 3.0], 0.5, vec![vec![1.0; 21]; 2]).unwrap(), 0.5).is_none());
        assert!(a.mix(&b, f64::NAN).is_none());
    }

    #[test]
    fn a_malformed_table_is_refused() {
        assert!(SurfaceShape::new(vec![1.0, 1.0], 0.5, vec![vec![0.0; 3]; 2]).is_err());
        assert!(SurfaceShape::new(vec![1.0], 0.5, vec![vec![0.0; 1]]).is_err());
        assert!(SurfaceShape::new(vec![1.0], 0.0, vec![vec![0.0; 3]]).is_err());
        assert!(SurfaceShape::new(vec![1.0], 0.5, vec![vec![0.0, f64::NAN]]).is_err());
        assert!(SurfaceShape::new(vec![1.0, 2.0], 0.5, vec![vec![0.0; 3]]).is_err());
    }
}
