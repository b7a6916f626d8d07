//! Small dense solvers on fixed-size arrays.

/// Solves `A x = b` for a symmetric positive-definite `A` by Cholesky decomposition, in place:
/// on success `b` holds `x` and `a` holds the factor. Only the first `n` rows and columns are used, so
/// one buffer serves problems of several sizes. Returns `false` (leaving `b` unspecified) when `A` is not
/// positive definite to working precision.
pub fn cholesky_solve<const N: usize>(a: &mut [[f32; N]; N], b: &mut [f32; N], n: usize) -> bool {
    if !cholesky_factor(a, n) {
        return false;
    }
    // Forward substitution L y = b.
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= a[i][k] * b[k];
        }
        b[i] = s / a[i][i];
    }
    // Back substitution L^T x = y.
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= a[k][i] * b[k];
        }
        b[i] = s / a[i][i];
    }
    true
}

/// Lower Cholesky factor of the leading `n x n` block of `a`, in place (the strict upper triangle is
/// left untouched). Returns `false` when a pivot is not positive.
pub fn cholesky_factor<const N: usize>(a: &mut [[f32; N]; N], n: usize) -> bool {
    for j in 0..n {
        let mut d = a[j][j];
        for k in 0..j {
            d -= a[j][k] * a[j][k];
        }
        if !(d > 0.0) || !d.is_finite() {
            return false;
        }
        let d = libm::sqrtf(d);
        a[j][j] = d;
        for i in j + 1..n {
            let mut s = a[i][j];
            for k in 0..j {
                s -= a[i][k] * a[j][k];
            }
            a[i][j] = s / d;
        }
    }
    true
}

/// Inverse of a symmetric positive-definite matrix (leading `n x n` block), or `false`.
pub fn spd_inverse<const N: usize>(a: &[[f32; N]; N], out: &mut [[f32; N]; N], n: usize) -> bool {
    let mut f = *a;
    if !cholesky_factor(&mut f, n) {
        return false;
    }
    for col in 0..n {
        let mut e = [0.0f32; N];
        e[col] = 1.0;
        for i in 0..n {
            let mut s = e[i];
            for k in 0..i {
                s -= f[i][k] * e[k];
            }
            e[i] = s / f[i][i];
        }
        for i in (0..n).rev() {
            let mut s = e[i];
            for k in i + 1..n {
                s -= f[k][i] * e[k];
            }
            e[i] = s / f[i][i];
        }
        for i in 0..n {
            out[i][col] = e[i];
        }
    }
    true
}

/// Eigen decomposition of the symmetric 2x2 matrix `[[a, b], [b, c]]`.
///
/// Returns `(l_small, l_large, v_small)`: the eigenvalues in increasing order and the unit eigenvector of the
/// smaller one. The formulation avoids cancellation when `b` is tiny.
pub fn sym2_eigen(a: f32, b: f32, c: f32) -> (f32, f32, [f32; 2]) {
    let half_diff = 0.5 * (a - c);
    let r = libm::hypotf(half_diff, b);
    let mean = 0.5 * (a + c);
    let l_large = mean + r;
    // det = l_small * l_large; computing l_small from it is exact when l_small << l_large.
    let det = a * c - b * b;
    let l_small = if l_large.abs() > 1e-30 { det / l_large } else { mean - r };
    // Eigenvector of l_large is (cos t, sin t) with tan(2t) = 2b / (a - c); the small one is perpendicular.
    let t = 0.5 * libm::atan2f(b, half_diff);
    let v_small = [-crate::trig::sin(t), crate::trig::cos(t)];
    (l_small, l_large, v_small)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cholesky_solves_spd() {
        let mut a = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]];
        let a0 = a;
        let x = [1.0, -2.0, 0.5];
        let mut b = [0.0; 3];
        for i in 0..3 {
            for j in 0..3 {
                b[i] += a0[i][j] * x[j];
            }
        }
        assert!(cholesky_solve(&mut a, &mut b, 3));
        for i in 0..3 {
            assert!((b[i] - x[i]).abs() < 1e-5);
        }
        let mut bad = [[1.0, 2.0], [2.0, 1.0]];
        let mut rhs = [1.0, 1.0];
        assert!(!cholesky_solve(&mut bad, &mut rhs, 2));
    }

    #[test]
    fn inverse_of_spd() {
        let a = [[4.0, 1.0], [1.0, 3.0]];
        let mut inv = [[0.0; 2]; 2];
        assert!(spd_inverse(&a, &mut inv, 2));
        let d = 11.0;
        assert!((inv[0][0] - 3.0 / d).abs() < 1e-6 && (inv[0][1] + 1.0 / d).abs() < 1e-6);
    }

    #[test]
    fn eigen_2x2() {
        // Scatter of points along a direction at 30 degrees with small spread across it.
        let t = 30f32.to_radians();
        let (ct, st) = (t.cos(), t.sin());
        let (l1, l2) = (100.0f32, 1e-4f32);
        let a = l1 * ct * ct + l2 * st * st;
        let b = (l1 - l2) * ct * st;
        let c = l1 * st * st + l2 * ct * ct;
        let (s, l, v) = sym2_eigen(a, b, c);
        assert!((l - l1).abs() < 1e-3);
        assert!((s - l2).abs() < 2e-5, "{s}");
        assert!((v[0] * ct + v[1] * st).abs() < 1e-6);
    }
}
