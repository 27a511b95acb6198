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

impl Factor {
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
