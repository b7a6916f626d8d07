use crate::{Mat3, Vec3};

/// A unit quaternion `w + xi + yj + zk` (Hamilton convention) representing a rotation.
///
/// `q.rotate(v)` maps a vector from the frame the quaternion describes (e.g. body) into the reference
/// frame (e.g. world): `q` is "world from body".
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Quat {
    /// Scalar part.
    pub w: f32,
    /// i part.
    pub x: f32,
    /// j part.
    pub y: f32,
    /// k part.
    pub z: f32,
}

impl Default for Quat {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Quat {
    /// No rotation.
    pub const IDENTITY: Quat = Quat { w: 1.0, x: 0.0, y: 0.0, z: 0.0 };

    /// Builds a quaternion (not normalised).
    pub const fn new(w: f32, x: f32, y: f32, z: f32) -> Self {
        Self { w, x, y, z }
    }

    /// Hamilton product `self * o`.
    pub fn mul(&self, o: &Quat) -> Quat {
        Quat {
            w: self.w * o.w - self.x * o.x - self.y * o.y - self.z * o.z,
            x: self.w * o.x + self.x * o.w + self.y * o.z - self.z * o.y,
            y: self.w * o.y - self.x * o.z + self.y * o.w + self.z * o.x,
            z: self.w * o.z + self.x * o.y - self.y * o.x + self.z * o.w,
        }
    }

    /// Conjugate (the inverse rotation for a unit quaternion).
    pub fn conj(&self) -> Quat {
        Quat { w: self.w, x: -self.x, y: -self.y, z: -self.z }
    }

    /// Normalised copy; the identity if the norm is zero or not finite.
    pub fn normalized(&self) -> Quat {
        let n = libm::sqrtf(self.w * self.w + self.x * self.x + self.y * self.y + self.z * self.z);
        if n > 1e-20 && n.is_finite() {
            let s = 1.0 / n;
            let q = Quat { w: self.w * s, x: self.x * s, y: self.y * s, z: self.z * s };
            if q.w < 0.0 { Quat { w: -q.w, x: -q.x, y: -q.y, z: -q.z } } else { q }
        } else {
            Quat::IDENTITY
        }
    }

    /// The rotation by the rotation vector `w` (axis times angle, radians).
    pub fn from_rotvec(w: Vec3) -> Quat {
        let th2 = w.norm_sq();
        if th2 < 1e-12 {
            // Second-order series keeps small gyro increments exact to f32 precision.
            let s = 0.5 - th2 / 48.0;
            return Quat { w: 1.0 - th2 / 8.0, x: w.x * s, y: w.y * s, z: w.z * s };
        }
        let th = libm::sqrtf(th2);
        let (sin, cos) = crate::trig::sin_cos(0.5 * th);
        let s = sin / th;
        Quat { w: cos, x: w.x * s, y: w.y * s, z: w.z * s }
    }

    /// The rotation vector (axis times angle, radians, angle in `[0, pi]`) of this rotation: the inverse of
    /// [`Quat::from_rotvec`].
    pub fn to_rotvec(&self) -> Vec3 {
        // q and -q are the same rotation: take the one with w >= 0 for the shorter angle.
        let q = if self.w < 0.0 { Quat { w: -self.w, x: -self.x, y: -self.y, z: -self.z } } else { *self };
        let v = Vec3::new(q.x, q.y, q.z);
        let s = v.norm();
        if s < 1e-6 {
            // 2 asin(s) / s = 2 (1 + s^2 / 6 + ...), and w ~ 1.
            return v * (2.0 / q.w.max(1e-6));
        }
        let angle = 2.0 * libm::atan2f(s, q.w);
        v * (angle / s)
    }

    /// Rotation matrix equal to this quaternion.
    pub fn to_mat3(&self) -> Mat3 {
        let (w, x, y, z) = (self.w, self.x, self.y, self.z);
        Mat3::from_rows(
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
            [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
            [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
        )
    }

    /// Quaternion of a rotation matrix (Shepperd's method).
    pub fn from_mat3(m: &Mat3) -> Quat {
        let m = &m.m;
        let tr = m[0][0] + m[1][1] + m[2][2];
        let q = if tr > 0.0 {
            let s = libm::sqrtf(tr + 1.0) * 2.0;
            Quat {
                w: 0.25 * s,
                x: (m[2][1] - m[1][2]) / s,
                y: (m[0][2] - m[2][0]) / s,
                z: (m[1][0] - m[0][1]) / s,
            }
        } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
            let s = libm::sqrtf(1.0 + m[0][0] - m[1][1] - m[2][2]) * 2.0;
            Quat {
                w: (m[2][1] - m[1][2]) / s,
                x: 0.25 * s,
                y: (m[0][1] + m[1][0]) / s,
                z: (m[0][2] + m[2][0]) / s,
            }
        } else if m[1][1] > m[2][2] {
            let s = libm::sqrtf(1.0 + m[1][1] - m[0][0] - m[2][2]) * 2.0;
            Quat {
                w: (m[0][2] - m[2][0]) / s,
                x: (m[0][1] + m[1][0]) / s,
                y: 0.25 * s,
                z: (m[1][2] + m[2][1]) / s,
            }
        } else {
            let s = libm::sqrtf(1.0 + m[2][2] - m[0][0] - m[1][1]) * 2.0;
            Quat {
                w: (m[1][0] - m[0][1]) / s,
                x: (m[0][2] + m[2][0]) / s,
                y: (m[1][2] + m[2][1]) / s,
                z: 0.25 * s,
            }
        };
        q.normalized()
    }

    /// Rotates `v` (from the described frame into the reference frame).
    pub fn rotate(&self, v: Vec3) -> Vec3 {
        let u = Vec3::new(self.x, self.y, self.z);
        let t = u.cross(v) * 2.0;
        v + t * self.w + u.cross(t)
    }

    /// Rotates `v` by the inverse rotation (from the reference frame into the described frame).
    pub fn inverse_rotate(&self, v: Vec3) -> Vec3 {
        self.conj().rotate(v)
    }

    /// True when all components are finite.
    pub fn is_finite(&self) -> bool {
        self.w.is_finite() && self.x.is_finite() && self.y.is_finite() && self.z.is_finite()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matrix_round_trip_and_rotation_agree() {
        let m = Mat3::from_euler_zyx(0.3, -0.2, 2.5);
        let q = Quat::from_mat3(&m);
        let v = Vec3::new(0.3, -1.0, 2.0);
        assert!((q.rotate(v) - m * v).norm() < 1e-5);
        assert!((q.inverse_rotate(m * v) - v).norm() < 1e-5);
        let m2 = q.to_mat3();
        assert!(m.angle_to(&m2) < 1e-4);
    }

    #[test]
    fn rotvec_matches_exp() {
        let w = Vec3::new(0.2, -0.4, 0.1);
        assert!(Quat::from_rotvec(w).to_mat3().angle_to(&Mat3::exp_so3(w)) < 1e-5);
        let small = Vec3::new(1e-7, -2e-7, 3e-7);
        assert!(Quat::from_rotvec(small).to_mat3().angle_to(&Mat3::exp_so3(small)) < 1e-6);
        for w in [w, small, Vec3::new(0.0, 3.0, 0.1), Vec3::new(2e-4, 1e-4, -3e-4)] {
            let back = Quat::from_rotvec(w).to_rotvec();
            assert!((back - w).norm() <= 1e-5 * w.norm().max(1e-3), "{w:?} -> {back:?}");
            // The same rotation with the opposite sign of the quaternion.
            let q = Quat::from_rotvec(w);
            let neg = Quat::new(-q.w, -q.x, -q.y, -q.z).to_rotvec();
            assert!((neg - w).norm() <= 1e-5 * w.norm().max(1e-3));
        }
    }
}
