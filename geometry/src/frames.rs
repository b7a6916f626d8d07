//! The project's frames (written down once; `docs/frames.md` explains them with figures).
//!
//! - **World `W`**: origin on the floor at the wall, below the line's `x = 0` end. `x` runs along the wall and the
//!   line, `y` is perpendicular to the wall and points from the wall to the vehicle (so `y` is the distance to the
//!   wall), `z` is up. The wall is the plane `y = 0`, the floor the plane `z = 0`. Right-handed.
//! - **Navigation `N`**: the world frame turned so that its `x` axis points at the wall: `x_N = -y_W`,
//!   `y_N = +x_W`, `z_N = +z_W`. Attitude angles are measured from it, so roll, pitch and yaw are all zero when
//!   the vehicle is level and faces the wall.
//! - **Body `B`**: FLU (`x` forward, `y` left, `z` up), origin at the centre of mass.
//!   Attitude: `R_WB = R_WN * Rz(yaw) * Ry(pitch) * Rx(roll)`. Positive pitch puts the nose down (the vehicle
//!   accelerates forward), positive roll puts the right side down (it accelerates to its right).
//! - **Camera `C`**: OpenCV convention: `x` right in the image, `y` down, `z` along the optical axis. Pixel
//!   coordinates have integer values at pixel centres.
use crate::{Mat3, Vec3};

/// `R_WN`: navigation frame (x toward the wall) to world frame.
pub const WORLD_FROM_NAV: Mat3 = Mat3 { m: [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]] };

/// `R_BC` of a camera looking along the body's forward axis, image top up.
pub const BODY_FROM_FORWARD_CAMERA: Mat3 = Mat3 { m: [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]] };

/// `R_BC` of a camera looking down along `-z_B`, image top toward the body's front.
pub const BODY_FROM_DOWN_CAMERA: Mat3 = Mat3 { m: [[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]] };

/// Roll, pitch and yaw (radians) of a vehicle attitude, measured from the navigation frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Attitude {
    /// Rotation about body x (rad).
    pub roll: f32,
    /// Rotation about body y (rad).
    pub pitch: f32,
    /// Rotation about the vertical (rad); zero when facing the wall.
    pub yaw: f32,
}

impl Attitude {
    /// Builds an attitude from angles in radians.
    pub const fn new(roll: f32, pitch: f32, yaw: f32) -> Self {
        Self { roll, pitch, yaw }
    }

    /// `R_WB` for this attitude.
    pub fn world_from_body(&self) -> Mat3 {
        WORLD_FROM_NAV.mul_mat(&Mat3::from_euler_zyx(self.roll, self.pitch, self.yaw))
    }

    /// Attitude of a world-from-body rotation.
    pub fn from_world_from_body(r_wb: &Mat3) -> Self {
        let (roll, pitch, yaw) = WORLD_FROM_NAV.transpose().mul_mat(r_wb).to_euler_zyx();
        Self { roll, pitch, yaw }
    }
}

/// The world "up" direction expressed in the body frame, for a world-from-body rotation.
pub fn up_in_body(r_wb: &Mat3) -> Vec3 {
    r_wb.tmul_vec(Vec3::Z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_vehicle_facing_the_wall() {
        let r_wb = Attitude::default().world_from_body();
        // Forward is toward the wall (-y world), left is +x world, up is up.
        assert_eq!(r_wb * Vec3::X, Vec3::new(0.0, -1.0, 0.0));
        assert_eq!(r_wb * Vec3::Y, Vec3::new(1.0, 0.0, 0.0));
        assert_eq!(r_wb * Vec3::Z, Vec3::Z);
        // The forward camera looks at the wall, image right is -x world, image down is -z world.
        let r_wc = r_wb * BODY_FROM_FORWARD_CAMERA;
        assert_eq!(r_wc * Vec3::Z, Vec3::new(0.0, -1.0, 0.0));
        assert_eq!(r_wc * Vec3::X, Vec3::new(-1.0, 0.0, 0.0));
        assert_eq!(r_wc * Vec3::Y, Vec3::new(0.0, 0.0, -1.0));
        assert_eq!(BODY_FROM_FORWARD_CAMERA.det(), 1.0);
        assert_eq!(BODY_FROM_DOWN_CAMERA.det(), 1.0);
        assert_eq!(BODY_FROM_DOWN_CAMERA * Vec3::Z, Vec3::new(0.0, 0.0, -1.0));
        assert_eq!(WORLD_FROM_NAV.det(), 1.0);
    }

    #[test]
    fn angle_signs() {
        // Positive pitch: nose down, thrust tilts toward the wall (-y world).
        let thrust = Attitude::new(0.0, 0.1, 0.0).world_from_body() * Vec3::Z;
        assert!(thrust.y < 0.0 && thrust.x.abs() < 1e-7);
        // Positive roll: right side down, thrust tilts to the vehicle's right (-x world when facing the wall).
        let thrust = Attitude::new(0.1, 0.0, 0.0).world_from_body() * Vec3::Z;
        assert!(thrust.x < 0.0 && thrust.y.abs() < 1e-7);
        // docs/frames.md: facing the wall, the downward camera's image x (to the right) is world -x, its image y
        // (down the image) world +y (away from the wall: the image's top is toward the nose), its axis world -z.
        let r_wc = Attitude::new(0.0, 0.0, 0.0).world_from_body() * BODY_FROM_DOWN_CAMERA;
        assert_eq!(r_wc * Vec3::X, Vec3::new(-1.0, 0.0, 0.0));
        assert_eq!(r_wc * Vec3::Y, Vec3::new(0.0, 1.0, 0.0));
        assert_eq!(r_wc * Vec3::Z, Vec3::new(0.0, 0.0, -1.0));
        let a = Attitude::new(0.05, -0.03, 0.2);
        let b = Attitude::from_world_from_body(&a.world_from_body());
        assert!(
            (a.roll - b.roll).abs() < 1e-6
                && (a.pitch - b.pitch).abs() < 1e-6
                && (a.yaw - b.yaw).abs() < 1e-6
        );
    }
}
