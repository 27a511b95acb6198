//! What the benchmarks share.

use sim::recording::Recording;

/// A copy of `rec` with every reading in contact moved by `k` picometres
/// (and `k` counted on): far below any reading's precision, but enough that
/// a fit of it ends on other bits than the last one and so finds none of the
/// last fit's solved states and paths in the layer model's memos, as a fit
/// of a new recording would not.
pub fn nudged(rec: &Recording, k: &mut u64) -> Recording {
    *k += 1;
    let mut out = rec.clone();
    for s in out.samples.iter_mut().filter(|s| s.gamma1_mm != 0.0) {
        s.gamma1_mm += *k as f64 * 1e-9;
    }
    out
}
