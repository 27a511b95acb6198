//! Numerics shared by the fits of a recording, the diagnosis and the frame
//! measurement: one least-squares solver ([`lm`]), the statistics
//! ([`stats`]; distributions through `statrs`) and a one-dimensional
//! minimiser ([`golden_min`]).

pub mod lm;
pub mod stats;

/// The minimum of `f` on `[lo, hi]` by golden-section search, to within `tol`
/// in the argument: `(argument, value)`. For a function with one minimum
/// there (elsewhere it finds a local one).
pub fn golden_min(f: impl Fn(f64) -> f64, lo: f64, hi: f64, tol: f64) -> (f64, f64) {
    const INV_PHI: f64 = 0.618_033_988_749_894_8;
    let (mut a, mut b) = (lo.min(hi), lo.max(hi));
    let mut x1 = b - INV_PHI * (b - a);
    let mut x2 = a + INV_PHI * (b - a);
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..200 {
        if b - a <= tol.abs() {
            break;
        }
        if f1 <= f2 {
            (b, x2, f2) = (x2, x1, f1);
            x1 = b - INV_PHI * (b - a);
            f1 = f(x1);
        } else {
            (a, x1, f1) = (x1, x2, f2);
            x2 = a + INV_PHI * (b - a);
            f2 = f(x2);
        }
    }
    if f1 <= f2 { (x1, f1) } else { (x2, f2) }
}

#[cfg(test)]
mod tests {
    #[test]
    fn golden_section_finds_a_parabolas_vertex_and_an_end_minimum() {
        let (x, v) = super::golden_min(|x| (x - 0.3).powi(2) + 2.0, -1.0, 4.0, 1e-9);
        // (to the square root of the float precision: f is flat there)
        assert!((x - 0.3).abs() < 1e-6 && (v - 2.0).abs() < 1e-12, "{x} {v}");
        // Decreasing over the whole interval: the upper end.
        let (x, _) = super::golden_min(|x| -x, 0.0, 1.0, 1e-9);
        assert!((x - 1.0).abs() < 1e-8, "{x}");
    }
}
