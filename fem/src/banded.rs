//! A symmetric positive-definite banded matrix and its Cholesky factor.

use crate::FemError;

/// Lower band of a symmetric matrix: `get(i, j)` for `i - bw <= j <= i`.
#[derive(Debug, Clone, PartialEq)]
pub struct Banded {
    n: usize,
    bw: usize,
    /// Row-major: row i holds columns i - bw ..= i at offsets 0 ..= bw.
    data: Vec<f64>,
}

impl Banded {
    pub fn zeros(n: usize, bw: usize) -> Self {
        Self { n, bw, data: vec![0.0; n * (bw + 1)] }
    }

    pub fn size(&self) -> usize {
        self.n
    }

    pub fn bandwidth(&self) -> usize {
        self.bw
    }

    fn idx(&self, i: usize, j: usize) -> usize {
        i * (self.bw + 1) + (j + self.bw - i)
    }

    /// A(i, j) of the symmetric matrix (0 outside the band).
    pub fn get(&self, i: usize, j: usize) -> f64 {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        if i - j > self.bw { 0.0 } else { self.data[self.idx(i, j)] }
    }

    /// Adds `v` to A(i, j) (and so to A(j, i)); entries outside the band are a bug.
    pub fn add(&mut self, i: usize, j: usize, v: f64) {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        debug_assert!(i - j <= self.bw, "({i}, {j}) outside the band {}", self.bw);
        let k = self.idx(i, j);
        self.data[k] += v;
    }

    fn set(&mut self, i: usize, j: usize, v: f64) {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        if i - j <= self.bw {
            let k = self.idx(i, j);
            self.data[k] = v;
        }
    }

    /// y = A x.
    pub fn mul(&self, x: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; self.n];
        for i in 0..self.n {
            for j in i.saturating_sub(self.bw)..=i {
                let a = self.data[self.idx(i, j)];
                y[i] += a * x[j];
                if j != i {
                    y[j] += a * x[i];
                }
            }
        }
        y
    }

    /// Impose x[d] = v: move the column to the right-hand side, then make row and
    /// column d the identity.
    pub fn constrain(&mut self, rhs: &mut [f64], d: usize, v: f64) {
        let lo = d.saturating_sub(self.bw);
        let hi = (d + self.bw).min(self.n - 1);
        for e in lo..=hi {
            if e != d {
                rhs[e] -= self.get(e, d) * v;
                self.set(e, d, 0.0);
            }
        }
        self.set(d, d, 1.0);
        rhs[d] = v;
    }

    /// Cholesky factor (A = L Lᵀ), kept for many right-hand sides. Each entry
    /// takes its row's dot product with an earlier row over their shared
    /// columns, both contiguous in the row-major band.
    pub fn factor(mut self) -> Result<Factor, FemError> {
        let (n, bw) = (self.n, self.bw);
        let w = bw + 1;
        for i in 0..n {
            let lo = i.saturating_sub(bw);
            let row_i = i * w + bw - i;
            for j in lo..=i {
                // Columns lo..j of rows i and j (lo is both rows' first shared column).
                let row_j = j * w + bw - j;
                let (a, b) = (&self.data[row_i + lo..row_i + j], &self.data[row_j + lo..row_j + j]);
                let s = self.data[row_i + j] - dot(a, b);
                if i == j {
                    if s.is_nan() || s <= 0.0 {
                        return Err(FemError::NotPositiveDefinite(i));
                    }
                    self.data[row_i + i] = s.sqrt();
                } else {
                    self.data[row_i + j] = s / self.data[row_j + j];
                }
            }
        }
        Ok(Factor { l: self })
    }

    /// Factor and solve A x = b once.
    pub fn solve(self, b: &[f64]) -> Result<Vec<f64>, FemError> {
        Ok(self.factor()?.solve(b))
    }
}

/// x · y, in four interleaved sums (a row of the band is up to its width,
/// tens to a hundred and more entries: one running sum would wait on each
/// addition).
fn dot(x: &[f64], y: &[f64]) -> f64 {
    let mut s = [0.0; 4];
    let (xc, yc) = (x.chunks_exact(4), y.chunks_exact(4));
    let tail: f64 = xc.remainder().iter().zip(yc.remainder()).map(|(a, b)| a * b).sum();
    for (a, b) in xc.zip(yc) {
        for k in 0..4 {
            s[k] += a[k] * b[k];
        }
    }
    (s[0] + s[1]) + (s[2] + s[3]) + tail
}

/// The Cholesky factor L of a banded SPD matrix.
pub struct Factor {
    l: Banded,
}

/// Right-hand sides solved together by [`Factor::solve_many`]: each row of the
/// factor is read once per block (the factor is megabytes, and a single solve is
/// bound by reading it).
const BLOCK: usize = 16;

impl Factor {
    /// The solutions for many right-hand sides, in blocks that share each pass
    /// over the factor; a block's forward pass starts at its first non-zero row
    /// (the surface compliances load one node at a time).
    pub fn solve_many(&self, rhs: &[Vec<f64>]) -> Vec<Vec<f64>> {
        let n = self.l.n;
        let mut out = Vec::with_capacity(rhs.len());
        for chunk in rhs.chunks(BLOCK) {
            let m = chunk.len();
            // Interleaved: y[i * m + r] is row i of right-hand side r.
            let mut y = vec![0.0; n * m];
            let mut start = n;
            for (r, b) in chunk.iter().enumerate() {
                for (i, &v) in b.iter().enumerate().take(n) {
                    if v != 0.0 {
                        y[i * m + r] = v;
                        start = start.min(i);
                    }
                }
            }
            self.solve_block(&mut y, m, start);
            for r in 0..m {
                out.push((0..n).map(|i| y[i * m + r]).collect());
            }
        }
        out
    }

    /// [`Factor::solve_many`] for right-hand sides of one non-zero entry each
    /// (`Some((row, value))`; `None` is a zero right-hand side), keeping of
    /// each solution only its entries at the rows `keep`, in that order: a
    /// body's surface compliance, with one block's workspace in memory
    /// instead of every full load and solution (the same numbers).
    pub fn solve_point_loads(&self, loads: &[Option<(usize, f64)>], keep: &[usize]) -> Vec<Vec<f64>> {
        let n = self.l.n;
        let mut out = Vec::with_capacity(loads.len());
        let mut y = Vec::new();
        for chunk in loads.chunks(BLOCK) {
            let m = chunk.len();
            y.clear();
            y.resize(n * m, 0.0);
            let mut start = n;
            for (r, load) in chunk.iter().enumerate() {
                if let Some((i, v)) = *load {
                    if i < n && v != 0.0 {
                        y[i * m + r] = v;
                        start = start.min(i);
                    }
                }
            }
            self.solve_block(&mut y, m, start);
            for r in 0..m {
                out.push(keep.iter().map(|&i| y[i * m + r]).collect());
            }
        }
        out
    }

    /// L Lᵀ x = y in place for the `m` right-hand sides interleaved in `y`
    /// (`y[i * m + r]`), all zero above row `start`.
    fn solve_block(&self, y: &mut [f64], m: usize, start: usize) {
        let l = &self.l;
        let (n, bw) = (l.n, l.bw);
        let w = bw + 1;
        let mut acc = vec![0.0; m];
        for i in start..n {
            let lo = i.saturating_sub(bw).max(start);
            let (done, rest) = y.split_at_mut(i * m);
            let row = &l.data[i * w + bw - i + lo..i * w + bw];
            acc.copy_from_slice(&rest[..m]);
            for (&lik, yk) in row.iter().zip(done[lo * m..].chunks_exact(m)) {
                acc.iter_mut().zip(yk).for_each(|(a, v)| *a -= lik * v);
            }
            let d = l.data[i * w + bw];
            rest[..m].iter_mut().zip(&acc).for_each(|(v, a)| *v = a / d);
        }
        // Lᵀ x = y by rows of L: x(i) is final once the rows below have
        // given their share, and row i then gives its share to the
        // columns before i (contiguous, where the column of Lᵀ is not).
        for i in (0..n).rev() {
            let lo = i.saturating_sub(bw);
            let (before, at) = y.split_at_mut(i * m);
            let d = l.data[i * w + bw];
            let xi = &mut at[..m];
            xi.iter_mut().for_each(|v| *v /= d);
            let row = &l.data[i * w + bw - i + lo..i * w + bw];
            for (&lik, yk) in row.iter().zip(before[lo * m..].chunks_exact_mut(m)) {
                yk.iter_mut().zip(xi.iter()).for_each(|(v, x)| *v -= lik * x);
            }
        }
    }

    /// x with L Lᵀ x = b.
    pub fn solve(&self, b: &[f64]) -> Vec<f64> {
        let l = &self.l;
        let (n, bw) = (l.n, l.bw);
        let w = bw + 1;
        let mut y = b.to_vec();
        for i in 0..n {
            let lo = i.saturating_sub(bw);
            let row = &l.data[i * w + bw - i + lo..i * w + bw];
            y[i] = (y[i] - dot(row, &y[lo..i])) / l.data[i * w + bw];
        }
        for i in (0..n).rev() {
            let lo = i.saturating_sub(bw);
            let (before, at) = y.split_at_mut(i);
            at[0] /= l.data[i * w + bw];
            let xi = at[0];
            let row = &l.data[i * w + bw - i + lo..i * w + bw];
            before[lo..].iter_mut().zip(row).for_each(|(v, a)| *v -= a * xi);
        }
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn many_right_hand_sides_solve_as_one_at_a_time() {
        let n = 60;
        let mut a = Banded::zeros(n, 3);
        for i in 0..n {
            a.add(i, i, 5.0 + (i % 3) as f64);
            if i > 0 {
                a.add(i, i - 1, -1.0);
            }
            if i > 2 {
                a.add(i, i - 3, 0.7);
            }
        }
        let f = a.factor().unwrap();
        // Unit loads (the forward pass skips their leading zeros) and a full
        // vector, more than one block of them.
        let mut rhs: Vec<Vec<f64>> = (0..n).step_by(3).map(|j| (0..n).map(|i| f64::from(i == j)).collect()).collect();
        rhs.push((0..n).map(|i| (i as f64 * 0.7).cos()).collect());
        let many = f.solve_many(&rhs);
        assert_eq!(many.len(), rhs.len());
        for (b, x) in rhs.iter().zip(&many) {
            let one = f.solve(b);
            for (p, q) in one.iter().zip(x) {
                assert!((p - q).abs() < 1e-13, "{p} vs {q}");
            }
        }
    }

    /// Point loads (one unit entry, some scaled, a zero load among them, over
    /// more than one block) solve to the rows kept of the full solutions, and
    /// those give back their load: the surface compliances without the full
    /// vectors.
    #[test]
    fn point_loads_keep_the_rows_of_the_full_solutions() {
        let (n, bw) = (61, 5);
        let mut a = Banded::zeros(n, bw);
        for i in 0..n {
            a.add(i, i, 3.0 + bw as f64 + (i % 4) as f64);
            for j in i.saturating_sub(bw)..i {
                a.add(i, j, ((i * 5 + j * 3) % 7) as f64 / 7.0 - 0.4);
            }
        }
        let f = a.clone().factor().unwrap();
        let loads: Vec<Option<(usize, f64)>> = (0..n)
            .step_by(2)
            .map(|j| if j == 10 { None } else { Some((j, if j % 3 == 0 { -1.0 } else { 2.5 })) })
            .collect();
        let keep: Vec<usize> = (0..n).rev().step_by(4).collect();
        let kept = f.solve_point_loads(&loads, &keep);
        assert_eq!(kept.len(), loads.len());
        for (load, x) in loads.iter().zip(&kept) {
            let mut b = vec![0.0; n];
            if let Some((j, v)) = *load {
                b[j] = v;
            }
            let full = f.solve(&b);
            let back = a.mul(&full);
            assert!(back.iter().zip(&b).all(|(p, q)| (p - q).abs() < 1e-12), "{load:?} does not solve");
            assert_eq!(x.len(), keep.len());
            for (&i, &v) in keep.iter().zip(x) {
                assert!(
                    (v - full[i]).abs() <= 1e-14 * full[i].abs().max(1e-3),
                    "{load:?}, row {i}: {v} vs {}",
                    full[i]
                );
            }
            if load.is_none() {
                assert!(x.iter().all(|&v| v == 0.0), "a zero load moves nothing");
            }
        }
    }

    #[test]
    fn every_bandwidth_solves_to_its_residual() {
        // Bands from the diagonal alone to full, rows whose lengths are not
        // multiples of the dot product's four sums: A x must give back b.
        let n = 37;
        for bw in [0, 1, 3, 4, 5, 9, 36] {
            let mut a = Banded::zeros(n, bw);
            for i in 0..n {
                a.add(i, i, 2.0 + bw as f64 + (i % 5) as f64);
                for j in i.saturating_sub(bw)..i {
                    a.add(i, j, ((i * 7 + j * 3) % 11) as f64 / 11.0 - 0.5);
                }
            }
            let rhs: Vec<Vec<f64>> = (0..20)
                .map(|r| (0..n).map(|i| if i < r { 0.0 } else { ((i + r) as f64 * 0.37).sin() }).collect())
                .collect();
            let f = a.clone().factor().unwrap();
            let many = f.solve_many(&rhs);
            for (b, x) in rhs.iter().zip(&many) {
                for (x, name) in [(x.clone(), "many"), (f.solve(b), "one")] {
                    let back = a.mul(&x);
                    let err = back.iter().zip(b).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
                    assert!(err < 1e-12, "bandwidth {bw}, {name}: residual {err}");
                }
            }
        }
    }

    #[test]
    fn solves_a_banded_spd_system() {
        // Tridiagonal second-difference matrix plus a band-2 coupling.
        let n = 50;
        let mut a = Banded::zeros(n, 2);
        for i in 0..n {
            a.add(i, i, 4.0);
            if i > 0 {
                a.add(i, i - 1, -1.0);
            }
            if i > 1 {
                a.add(i, i - 2, 0.5);
            }
        }
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.3).sin()).collect();
        let b = a.mul(&x);
        let back = a.clone().solve(&b).unwrap();
        for (p, q) in back.iter().zip(&x) {
            assert!((p - q).abs() < 1e-12);
        }
        // A constrained unknown takes its value and the rest still solve.
        let mut a2 = a.clone();
        let mut b2 = b.clone();
        a2.constrain(&mut b2, 7, x[7]);
        let back = a2.solve(&b2).unwrap();
        assert!((back[7] - x[7]).abs() < 1e-14 && (back[20] - x[20]).abs() < 1e-12);
        let mut bad = Banded::zeros(3, 1);
        bad.add(0, 0, 1.0);
        assert!(matches!(bad.solve(&[1.0, 1.0, 1.0]), Err(FemError::NotPositiveDefinite(1))));
    }
}
