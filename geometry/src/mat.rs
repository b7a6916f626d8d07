use crate::Vec3;
use core::ops::Mul;

/// A row-major 3x3 matrix of f32.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Mat3 {
    /// Rows.
    pub m: [[f32; 3]; 3],
}

impl Default for Mat3 {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Mat3 {
    /// The identity.
    pub const IDENTITY: Mat3 = Mat3 { m: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] };
    /// The zero matrix.
    pub const ZERO: Mat3 = Mat3 { m: [[0.0; 3]; 3] };

    /// From rows.
    pub const fn from_rows(r0: [f32; 3], r1: [f32; 3], r2: [f32; 3]) -> Self {
        Self { m: [r0, r1, r2] }
    }

    /// From three column vectors.
    pub fn from_cols(c0: Vec3, c1: Vec3, c2: Vec3) -> Self {
        Self { m: [[c0.x, c1.x, c2.x], [c0.y, c1.y, c2.y], [c0.z, c1.z, c2.z]] }
    }

    /// Column `j`.
    pub fn col(&self, j: usize) -> Vec3 {
        Vec3::new(self.m[0][j], self.m[1][j], self.m[2][j])
    }

    /// Row `i`.
    pub fn row(&self, i: usize) -> Vec3 {
        Vec3::from_array(self.m[i])
    }

    /// Transpose.
    pub fn transpose(&self) -> Self {
        let m = &self.m;
        Self { m: [[m[0][0], m[1][0], m[2][0]], [m[0][1], m[1][1], m[2][1]], [m[0][2], m[1][2], m[2][2]]] }
    }

    /// Matrix times vector.
    pub fn mul_vec(&self, v: Vec3) -> Vec3 {
        let m = &self.m;
        Vec3::new(
            m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z,
            m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
            m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z,
        )
    }

    /// Transpose times vector.
    pub fn tmul_vec(&self, v: Vec3) -> Vec3 {
        let m = &self.m;
        Vec3::new(
            m[0][0] * v.x + m[1][0] * v.y + m[2][0] * v.z,
            m[0][1] * v.x + m[1][1] * v.y + m[2][1] * v.z,
            m[0][2] * v.x + m[1][2] * v.y + m[2][2] * v.z,
        )
    }

    /// Matrix product `self * o`.
    pub fn mul_mat(&self, o: &Mat3) -> Mat3 {
        let mut r = Mat3::ZERO;
        for i in 0..3 {
            for j in 0..3 {
                r.m[i][j] = self.m[i][0] * o.m[0][j] + self.m[i][1] * o.m[1][j] + self.m[i][2] * o.m[2][j];
            }
        }
        r
    }

    /// Sum of two matrices.
    pub fn add(&self, o: &Mat3) -> Mat3 {
        let mut r = *self;
        for i in 0..3 {
            for j in 0..3 {
                r.m[i][j] += o.m[i][j];
            }
        }
        r
    }

    /// Scaled matrix.
    pub fn scale(&self, s: f32) -> Mat3 {
        let mut r = *self;
        for row in r.m.iter_mut() {
            for v in row.iter_mut() {
                *v *= s;
            }
        }
        r
    }

    /// Determinant.
    pub fn det(&self) -> f32 {
        let m = &self.m;
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    }

    /// Inverse, or `None` when the matrix is singular.
    pub fn inverse(&self) -> Option<Mat3> {
        let d = self.det();
        if d.abs() < 1e-30 || !d.is_finite() {
            return None;
        }
        let m = &self.m;
        let inv = 1.0 / d;
        Some(Mat3 {
            m: [
                [
                    (m[1][1] * m[2][2] - m[1][2] * m[2][1]) * inv,
                    (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * inv,
                    (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * inv,
                ],
                [
                    (m[1][2] * m[2][0] - m[1][0] * m[2][2]) * inv,
                    (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * inv,
                    (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * inv,
                ],
                [
                    (m[1][0] * m[2][1] - m[1][1] * m[2][0]) * inv,
                    (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * inv,
                    (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * inv,
                ],
            ],
        })
    }

    /// The skew-symmetric matrix `[v]x` with `[v]x w = v x w`.
    pub fn skew(v: Vec3) -> Mat3 {
        Mat3::from_rows([0.0, -v.z, v.y], [v.z, 0.0, -v.x], [-v.y, v.x, 0.0])
    }

    /// Rotation about x by `a` radians.
    pub fn rot_x(a: f32) -> Mat3 {
        let (s, c) = crate::trig::sin_cos(a);
        Mat3::from_rows([1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c])
    }

    /// Rotation about y by `a` radians.
    pub fn rot_y(a: f32) -> Mat3 {
        let (s, c) = crate::trig::sin_cos(a);
        Mat3::from_rows([c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c])
    }

    /// Rotation about z by `a` radians.
    pub fn rot_z(a: f32) -> Mat3 {
        let (s, c) = crate::trig::sin_cos(a);
        Mat3::from_rows([c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0])
    }

    /// `Rz(yaw) * Ry(pitch) * Rx(roll)`: the ZYX (yaw-pitch-roll) convention.
    pub fn from_euler_zyx(roll: f32, pitch: f32, yaw: f32) -> Mat3 {
        let (sr, cr) = crate::trig::sin_cos(roll);
        let (sp, cp) = crate::trig::sin_cos(pitch);
        let (sy, cy) = crate::trig::sin_cos(yaw);
        Mat3::from_rows(
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        )
    }

    /// Inverse of [`Mat3::from_euler_zyx`]: `(roll, pitch, yaw)` in radians.
    pub fn to_euler_zyx(&self) -> (f32, f32, f32) {
        let m = &self.m;
        // asin(-m20) as atan2 of sine and cosine: libm's asinf computes in f64, which the MCU emulates.
        let sp = crate::clamp_finite(-m[2][0], -1.0, 1.0);
        let pitch = libm::atan2f(sp, libm::sqrtf(m[0][0] * m[0][0] + m[1][0] * m[1][0]));
        let roll = libm::atan2f(m[2][1], m[2][2]);
        let yaw = libm::atan2f(m[1][0], m[0][0]);
        (roll, pitch, yaw)
    }

    /// Rotation by the rotation vector `w` (axis times angle), Rodrigues' formula.
    pub fn exp_so3(w: Vec3) -> Mat3 {
        let th2 = w.norm_sq();
        let k = Mat3::skew(w);
        let k2 = k.mul_mat(&k);
        let (a, b) = if th2 < 1e-8 {
            (1.0 - th2 / 6.0, 0.5 - th2 / 24.0)
        } else {
            let th = libm::sqrtf(th2);
            let (s, c) = crate::trig::sin_cos(th);
            (s / th, (1.0 - c) / th2)
        };
        Mat3::IDENTITY.add(&k.scale(a)).add(&k2.scale(b))
    }

    /// Rotation vector of a rotation matrix (inverse of [`Mat3::exp_so3`]).
    pub fn log_so3(&self) -> Vec3 {
        let m = &self.m;
        let tr = m[0][0] + m[1][1] + m[2][2];
        let c = crate::clamp_finite(0.5 * (tr - 1.0), -1.0, 1.0);
        let th = libm::acosf(c);
        let v = Vec3::new(m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1]);
        if th < 1e-4 {
            return v * 0.5;
        }
        if th > core::f32::consts::PI - 1e-3 {
            // Near pi: take the axis from the diagonal.
            let x = libm::sqrtf(((m[0][0] - c) / (1.0 - c)).max(0.0));
            let y = libm::sqrtf(((m[1][1] - c) / (1.0 - c)).max(0.0));
            let z = libm::sqrtf(((m[2][2] - c) / (1.0 - c)).max(0.0));
            let mut axis = Vec3::new(x, y, z);
            if m[0][1] + m[1][0] < 0.0 {
                axis.y = -axis.y;
            }
            if m[0][2] + m[2][0] < 0.0 {
                axis.z = -axis.z;
            }
            return axis * th;
        }
        v * (th / (2.0 * crate::trig::sin(th)))
    }

    /// Angle (radians) of the rotation `self^T * o`.
    pub fn angle_to(&self, o: &Mat3) -> f32 {
        self.transpose().mul_mat(o).log_so3().norm()
    }

    /// The nearest rotation (polar factor) of a nearly orthogonal matrix, by Newton iterations
    /// `R <- (R + R^-T)/2`. Returns `None` if the matrix is singular or has a negative determinant.
    pub fn orthonormalized(&self) -> Option<Mat3> {
        if self.det() <= 0.0 {
            return None;
        }
        let mut r = *self;
        for _ in 0..8 {
            let inv_t = r.inverse()?.transpose();
            let next = r.add(&inv_t).scale(0.5);
            let mut diff = 0.0f32;
            for i in 0..3 {
                for j in 0..3 {
                    diff = diff.max((next.m[i][j] - r.m[i][j]).abs());
                }
            }
            r = next;
            if diff < 1e-7 {
                break;
            }
        }
        Some(r)
    }

    /// True when all entries are finite.
    pub fn is_finite(&self) -> bool {
        self.m.iter().all(|r| r.iter().all(|v| v.is_finite()))
    }
}

impl Mul<Vec3> for Mat3 {
    type Output = Vec3;
    fn mul(self, v: Vec3) -> Vec3 {
        self.mul_vec(v)
    }
}

impl Mul<Mat3> for Mat3 {
    type Output = Mat3;
    fn mul(self, o: Mat3) -> Mat3 {
        self.mul_mat(&o)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &Mat3, b: &Mat3, tol: f32) -> bool {
        (0..3).all(|i| (0..3).all(|j| (a.m[i][j] - b.m[i][j]).abs() < tol))
    }

    #[test]
    fn euler_round_trip() {
        for &(r, p, y) in &[(0.1, -0.2, 0.3), (-0.5, 0.4, -2.9), (0.0, 0.0, 0.0), (1.0, -1.2, 3.0)] {
            let m = Mat3::from_euler_zyx(r, p, y);
            assert!((m.det() - 1.0).abs() < 1e-5);
            let (r2, p2, y2) = m.to_euler_zyx();
            assert!((r - r2).abs() < 1e-5 && (p - p2).abs() < 1e-5 && (y - y2).abs() < 1e-5);
            let m2 = Mat3::rot_z(y) * Mat3::rot_y(p) * Mat3::rot_x(r);
            assert!(close(&m, &m2, 1e-6));
        }
    }

    #[test]
    fn exp_log_round_trip() {
        for w in [Vec3::new(0.1, -0.2, 0.3), Vec3::new(1e-6, 0.0, 2e-6), Vec3::new(0.0, 3.0, 0.0)] {
            let r = Mat3::exp_so3(w);
            assert!((r.det() - 1.0).abs() < 1e-5);
            let w2 = r.log_so3();
            assert!((w - w2).norm() < 1e-4, "{w:?} {w2:?}");
        }
    }

    #[test]
    fn polar_fixes_a_perturbed_rotation() {
        let r = Mat3::from_euler_zyx(0.2, 0.1, -0.4);
        let mut p = r;
        p.m[0][1] += 0.01;
        p.m[2][0] -= 0.02;
        let q = p.orthonormalized().unwrap();
        assert!((q.det() - 1.0).abs() < 1e-5);
        let qtq = q.transpose() * q;
        assert!(close(&qtq, &Mat3::IDENTITY, 1e-5));
        assert!(r.angle_to(&q) < 0.02);
    }

    #[test]
    fn inverse_times_self_is_identity() {
        let a = Mat3::from_rows([2.0, 1.0, 0.5], [0.0, 3.0, 1.0], [1.0, 0.0, 4.0]);
        assert!(close(&(a * a.inverse().unwrap()), &Mat3::IDENTITY, 1e-6));
        assert!(Mat3::ZERO.inverse().is_none());
    }
}
