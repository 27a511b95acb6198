//! Small dense systems of the condensed contact problems: Gaussian elimination
//! for the general (frictional) ones, and a Cholesky factor whose leading blocks
//! solve every prefix of the surface nodes (docs/physics.md, "Finite-element
//! reference": a frictionless axisymmetric contact, and the stuck core of a
//! twisted one, is the set of nodes from the axis out to its edge).

/// Solve the dense system a x = b (Gaussian elimination with partial pivoting);
/// `None` when a pivot vanishes.
pub(crate) fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for c in 0..n {
        let p = (c..n).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[p][c].abs() < 1e-300 {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        let (top, bottom) = a.split_at_mut(c + 1);
        let pivot = &top[c];
        for (k, row) in bottom.iter_mut().enumerate() {
            let f = row[c] / pivot[c];
            if f != 0.0 {
                row[c..].iter_mut().zip(&pivot[c..]).for_each(|(x, y)| *x -= f * y);
                b[c + 1 + k] -= f * b[c];
            }
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = a[i][i + 1..].iter().zip(&x[i + 1..]).map(|(u, v)| u * v).sum();
        x[i] = (b[i] - s) / a[i][i];
    }
    Some(x)
}

/// The dot product of `a` and `b` (over the shorter), summed in four
/// interleaved partial sums: the substitutions' inner loop, which a single
/// running sum keeps from using the vector units (its additions must then
/// happen in order).
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    let tail: f64 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// The Cholesky factor L (row-major lower triangle) of a symmetric positive
/// definite matrix. The factor of a leading principal block is the leading block
/// of L, so one factorisation solves the system restricted to the first k
/// unknowns for every k, each at O(k²).
#[derive(Debug, Clone, Default)]
pub(crate) struct PrefixCholesky {
    n: usize,
    /// Row i holds L[i][0..=i] at offset i(i+1)/2.
    l: Vec<f64>,
    /// 1 / L[i][i]: the substitutions multiply by it (a division's latency
    /// would sit on their serial chain, once per unknown).
    inv_diag: Vec<f64>,
}

impl PrefixCholesky {
    /// Factor the n x n matrix whose (i, j) entry is `at(i, j)` (only j <= i is
    /// read). Rows past the first non-positive pivot are left out: `len()` tells
    /// how many leading unknowns the factor can solve for.
    #[cfg(test)]
    pub(crate) fn new(n: usize, at: impl Fn(usize, usize) -> f64) -> Self {
        let mut f = Self::empty();
        f.extend_to(n, at);
        f
    }

    /// A factor of nothing yet, to be grown with [`Self::extend_to`].
    pub(crate) fn empty() -> Self {
        Self { n: 0, l: Vec::new(), inv_diag: Vec::new() }
    }

    /// Factor further rows of the same matrix until `n` leading unknowns are
    /// solvable (the rows already factored are kept: a leading block's factor
    /// does not depend on what follows it), stopping at a non-positive pivot.
    /// Returns `len()`.
    pub(crate) fn extend_to(&mut self, n: usize, at: impl Fn(usize, usize) -> f64) -> usize {
        let l = &mut self.l;
        for i in self.n..n {
            let row0 = l.len();
            let mut ok = true;
            for j in 0..=i {
                let rj = j * (j + 1) / 2;
                let v = at(i, j) - dot(&l[row0..row0 + j], &l[rj..rj + j]);
                if j == i {
                    if !(v > 0.0 && v.is_finite()) {
                        ok = false;
                        break;
                    }
                    l.push(v.sqrt());
                    self.inv_diag.push(1.0 / v.sqrt());
                } else {
                    l.push(v * self.inv_diag[j]);
                }
            }
            if !ok {
                l.truncate(row0);
                break;
            }
            self.n = i + 1;
        }
        self.n
    }

    /// How many leading unknowns can be solved for.
    pub(crate) fn len(&self) -> usize {
        self.n
    }

    /// x with A[..k][..k] x = b, k = b.len() (at most `len()`).
    pub(crate) fn solve_prefix(&self, b: &[f64]) -> Option<Vec<f64>> {
        if b.len() > self.n {
            return None;
        }
        let mut y = Vec::with_capacity(b.len());
        self.forward_extend(&mut y, b.len(), |i| b[i]);
        self.backward(y)
    }

    /// Row i of L (its entries up to the diagonal).
    fn row(&self, i: usize) -> &[f64] {
        &self.l[i * (i + 1) / 2..i * (i + 1) / 2 + i + 1]
    }

    /// Extend y = L⁻¹ b (the first `y.len()` entries already there; `b` by
    /// index) to `k` entries, at most `len()`. A forward substitution's leading
    /// entries are those of any longer one, so a right-hand side the contact
    /// keeps meeting is substituted once, as far as it is needed.
    pub(crate) fn forward_extend(&self, y: &mut Vec<f64>, k: usize, b: impl Fn(usize) -> f64) {
        for i in y.len()..k.min(self.n) {
            let r = self.row(i);
            let s = dot(&r[..i], &y[..i]);
            y.push((b(i) - s) * self.inv_diag[i]);
        }
    }

    /// x with Lᵀ x = y on the leading y.len() unknowns (at most `len()`).
    pub(crate) fn backward(&self, mut y: Vec<f64>) -> Option<Vec<f64>> {
        let k = y.len();
        if k > self.n {
            return None;
        }
        // Lᵀ x = y by columns of Lᵀ, i.e. rows of L (contiguous).
        for i in (0..k).rev() {
            let r = self.row(i);
            y[i] *= self.inv_diag[i];
            let xi = y[i];
            y[..i].iter_mut().zip(&r[..i]).for_each(|(v, l)| *v -= l * xi);
        }
        Some(y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A symmetric positive definite matrix with the decay of a surface compliance.
    fn spd(n: usize) -> Vec<Vec<f64>> {
        (0..n)
            .map(|i| {
                (0..n).map(|j| 1.0 / (1.0 + (i as f64 - j as f64).abs()) + if i == j { 0.5 } else { 0.0 }).collect()
            })
            .collect()
    }

    #[test]
    fn every_prefix_solves_as_elimination_does() {
        let a = spd(12);
        let f = PrefixCholesky::new(12, |i, j| a[i][j]);
        assert_eq!(f.len(), 12);
        for k in 1..=12 {
            let b: Vec<f64> = (0..k).map(|i| (i as f64 * 0.7).sin() + 1.0).collect();
            let sub: Vec<Vec<f64>> = a[..k].iter().map(|r| r[..k].to_vec()).collect();
            let x = f.solve_prefix(&b).unwrap();
            let y = solve(sub.clone(), b.clone()).unwrap();
            for i in 0..k {
                assert!((x[i] - y[i]).abs() < 1e-12, "k {k} i {i}: {} vs {}", x[i], y[i]);
                let r: f64 = (0..k).map(|j| sub[i][j] * x[j]).sum();
                assert!((r - b[i]).abs() < 1e-12);
            }
        }
        assert!(f.solve_prefix(&[1.0; 13]).is_none());
    }

    #[test]
    fn a_factor_grown_in_pieces_is_the_factor_of_the_whole() {
        let a = spd(10);
        let whole = PrefixCholesky::new(10, |i, j| a[i][j]);
        let mut grown = PrefixCholesky::empty();
        for k in [3, 3, 7, 10] {
            assert_eq!(grown.extend_to(k, |i, j| a[i][j]), k);
        }
        assert_eq!(grown.l, whole.l);
    }

    #[test]
    fn the_factor_stops_at_a_non_positive_pivot() {
        let mut a = spd(6);
        a[3][3] = -1.0;
        let f = PrefixCholesky::new(6, |i, j| a[i][j]);
        assert_eq!(f.len(), 3);
    }

    #[test]
    fn elimination_pivots_and_refuses_a_singular_system() {
        let x = solve(vec![vec![0.0, 2.0], vec![3.0, 1.0]], vec![4.0, 5.0]).unwrap();
        assert!((x[0] - 1.0).abs() < 1e-15 && (x[1] - 2.0).abs() < 1e-15);
        assert!(solve(vec![vec![1.0, 2.0], vec![2.0, 4.0]], vec![1.0, 1.0]).is_none());
    }
}
