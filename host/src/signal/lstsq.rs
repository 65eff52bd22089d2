//! Least squares one row at a time, in memory bounded by the number of columns.

use nalgebra::{DMatrix, DVector};

/// Least squares one row at a time: the upper-triangular factor of the augmented matrix
/// `[A y]` (p + 1 columns) updated by Givens rotations, as stable as a QR of the whole
/// matrix and exact for a rank-deficient `A` (a zero column leaves its rotations idle).
pub struct StreamingLeastSquares {
    /// Row-major (p + 1)², upper triangle used.
    r: Vec<f64>,
    m: usize,
    rows: usize,
    scratch: Vec<f64>,
}

impl StreamingLeastSquares {
    /// `p` regressor columns (the response is the row's last value).
    pub fn new(p: usize) -> Self {
        let m = p + 1;
        Self {
            r: vec![0.0; m * m],
            m,
            rows: 0,
            scratch: vec![0.0; m],
        }
    }

    /// One row `[a_1 … a_p, y]`.
    pub fn push(&mut self, row: &[f64]) {
        let m = self.m;
        let mut x = std::mem::take(&mut self.scratch);
        x.copy_from_slice(&row[..m]);
        for k in 0..m {
            if x[k] == 0.0 {
                continue;
            }
            let rkk = self.r[k * m + k];
            let h = rkk.hypot(x[k]);
            let (c, s) = (rkk / h, x[k] / h);
            let row_k = &mut self.r[k * m..(k + 1) * m];
            for (a, b) in row_k[k..].iter_mut().zip(&mut x[k..]) {
                let (ra, xb) = (*a, *b);
                *a = c * ra + s * xb;
                *b = c * xb - s * ra;
            }
        }
        self.scratch = x;
        self.rows += 1;
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    /// ‖y − A·x̂‖² of the least-squares fit. Directions of `A` with a singular value below
    /// 1e-10 of the largest (a duplicated column, which the rotations leave as rounding
    /// noise rather than exact zeros) are left out of the fit, as a truncated SVD of the
    /// whole matrix would: `R` has `A`'s singular values.
    pub fn residual_sum_of_squares(&self) -> f64 {
        let (m, p) = (self.m, self.m - 1);
        let ryy = self.r[m * m - 1];
        let rp = DMatrix::from_fn(p, p, |i, j| if j >= i { self.r[i * m + j] } else { 0.0 });
        let rhs = DVector::from_fn(p, |i, _| self.r[i * m + p]);
        let svd = rp.clone().svd(true, true);
        let tol = 1e-10 * svd.singular_values.max();
        let left = match svd.solve(&rhs, tol) {
            Ok(x) => (rhs - rp * x).norm_squared(),
            Err(_) => rhs.norm_squared(),
        };
        ryy * ryy + left
    }
}

#[cfg(test)]
mod tests {
    use super::StreamingLeastSquares;
    use nalgebra::{DMatrix, DVector};

    /// The row-by-row fit leaves the same residual as the SVD of the whole matrix, also
    /// with a zero column (a non-interference term's regressor) and a duplicated one.
    #[test]
    fn residual_matches_the_whole_matrix_svd() {
        let n = 500;
        let p = 5;
        let a = DMatrix::from_fn(n, p, |i, j| match j {
            0 => 1.0,
            1 => (i as f64 * 0.37).sin() * 300.0,
            2 => 0.0,
            3 => (i as f64 * 0.11).cos() * 20.0,
            _ => (i as f64 * 0.37).sin() * 300.0, // = column 1
        });
        let y = DVector::from_fn(n, |i, _| {
            5.0 + 0.3 * a[(i, 1)] - 2.0 * a[(i, 3)] + ((i * 7919) % 101) as f64 * 0.01
        });
        let x = a.clone().svd(true, true).solve(&y, 1e-9).unwrap();
        let svd_rss = (&y - &a * x).norm_squared();
        let mut ls = StreamingLeastSquares::new(p);
        for i in 0..n {
            let mut row: Vec<f64> = (0..p).map(|j| a[(i, j)]).collect();
            row.push(y[i]);
            ls.push(&row);
        }
        let rss = ls.residual_sum_of_squares();
        assert!(svd_rss > 1.0, "the noise leaves a residual: {svd_rss}");
        assert!(
            (rss / svd_rss - 1.0).abs() < 1e-9,
            "streamed {rss} vs svd {svd_rss}"
        );
    }
}
