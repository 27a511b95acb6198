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

    /// Cholesky factor (A = L Lᵀ), kept for many right-hand sides.
    pub fn factor(mut self) -> Result<Factor, FemError> {
        let (n, bw) = (self.n, self.bw);
        for i in 0..n {
            for j in i.saturating_sub(bw)..=i {
                let mut s = self.data[self.idx(i, j)];
                for k in i.saturating_sub(bw).max(j.saturating_sub(bw))..j {
                    s -= self.data[self.idx(i, k)] * self.data[self.idx(j, k)];
                }
                if i == j {
                    if s.is_nan() || s <= 0.0 {
                        return Err(FemError::NotPositiveDefinite(i));
                    }
                    let k = self.idx(i, i);
                    self.data[k] = s.sqrt();
                } else {
                    let k = self.idx(i, j);
                    self.data[k] = s / self.data[self.idx(j, j)];
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
        let l = &self.l;
        let (n, bw) = (l.n, l.bw);
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
            let mut acc = vec![0.0; m];
            for i in start..n {
                acc.copy_from_slice(&y[i * m..(i + 1) * m]);
                for k in i.saturating_sub(bw).max(start)..i {
                    let lik = l.data[l.idx(i, k)];
                    let yk = &y[k * m..(k + 1) * m];
                    acc.iter_mut().zip(yk).for_each(|(a, v)| *a -= lik * v);
                }
                let d = l.data[l.idx(i, i)];
                y[i * m..(i + 1) * m].iter_mut().zip(&acc).for_each(|(v, a)| *v = a / d);
            }
            for i in (0..n).rev() {
                acc.copy_from_slice(&y[i * m..(i + 1) * m]);
                for k in i + 1..=(i + bw).min(n - 1) {
                    let lki = l.data[l.idx(k, i)];
                    let yk = &y[k * m..(k + 1) * m];
                    acc.iter_mut().zip(yk).for_each(|(a, v)| *a -= lki * v);
                }
                let d = l.data[l.idx(i, i)];
                y[i * m..(i + 1) * m].iter_mut().zip(&acc).for_each(|(v, a)| *v = a / d);
            }
            for r in 0..m {
                out.push((0..n).map(|i| y[i * m + r]).collect());
            }
        }
        out
    }

    /// x with L Lᵀ x = b.
    pub fn solve(&self, b: &[f64]) -> Vec<f64> {
        let l = &self.l;
        let (n, bw) = (l.n, l.bw);
        let mut y = b.to_vec();
        for i in 0..n {
            let mut s = y[i];
            for k in i.saturating_sub(bw)..i {
                s -= l.data[l.idx(i, k)] * y[k];
            }
            y[i] = s / l.data[l.idx(i, i)];
        }
        for i in (0..n).rev() {
            let mut s = y[i];
            for k in i + 1..=(i + bw).min(n - 1) {
                s -= l.data[l.idx(k, i)] * y[k];
            }
            y[i] = s / l.data[l.idx(i, i)];
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
