//! Pinhole camera with optional Brown-Conrady distortion.
use geometry::Vec2;

/// Radial (`k1, k2, k3`) and tangential (`p1, p2`) distortion coefficients, OpenCV's convention.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Distortion {
    /// Radial r^2 coefficient.
    pub k1: f32,
    /// Radial r^4 coefficient.
    pub k2: f32,
    /// Tangential coefficient 1.
    pub p1: f32,
    /// Tangential coefficient 2.
    pub p2: f32,
    /// Radial r^6 coefficient.
    pub k3: f32,
}

impl Distortion {
    /// True when all coefficients are zero.
    pub fn is_zero(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0 && self.p1 == 0.0 && self.p2 == 0.0 && self.k3 == 0.0
    }
}

/// Intrinsics of a camera. Pixel coordinates have integer values at pixel centres (OpenCV).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CameraModel {
    /// Image width (px).
    pub width: u16,
    /// Image height (px).
    pub height: u16,
    /// Focal length along x (px).
    pub fx: f32,
    /// Focal length along y (px).
    pub fy: f32,
    /// Principal point x (px).
    pub cx: f32,
    /// Principal point y (px).
    pub cy: f32,
    /// Lens distortion.
    pub distortion: Distortion,
}

impl CameraModel {
    /// The paper's forward camera: 640x480, fx = fy = 320 px (90 degree horizontal field), centre (320, 240).
    pub const PAPER_FORWARD: CameraModel = CameraModel {
        width: 640,
        height: 480,
        fx: 320.0,
        fy: 320.0,
        cx: 320.0,
        cy: 240.0,
        distortion: Distortion { k1: 0.0, k2: 0.0, p1: 0.0, p2: 0.0, k3: 0.0 },
    };

    /// Mean focal length (px), used to express normalised distances in pixels.
    pub fn focal_px(&self) -> f32 {
        0.5 * (self.fx + self.fy)
    }

    /// Normalised, undistorted image coordinates of a pixel position.
    pub fn pixel_to_normalized(&self, p: Vec2) -> Vec2 {
        let d = Vec2::new((p.x - self.cx) / self.fx, (p.y - self.cy) / self.fy);
        if self.distortion.is_zero() { d } else { self.undistort(d) }
    }

    /// Pixel position of normalised, undistorted image coordinates.
    pub fn normalized_to_pixel(&self, n: Vec2) -> Vec2 {
        let d = if self.distortion.is_zero() { n } else { self.distort(n) };
        Vec2::new(self.fx * d.x + self.cx, self.fy * d.y + self.cy)
    }

    /// Applies the distortion model to normalised coordinates.
    pub fn distort(&self, n: Vec2) -> Vec2 {
        let k = &self.distortion;
        let r2 = n.x * n.x + n.y * n.y;
        let radial = 1.0 + r2 * (k.k1 + r2 * (k.k2 + r2 * k.k3));
        Vec2::new(
            n.x * radial + 2.0 * k.p1 * n.x * n.y + k.p2 * (r2 + 2.0 * n.x * n.x),
            n.y * radial + k.p1 * (r2 + 2.0 * n.y * n.y) + 2.0 * k.p2 * n.x * n.y,
        )
    }

    /// Inverts [`CameraModel::distort`] by fixed-point iteration (the usual 10 steps of OpenCV's
    /// `undistortPoints`, continued until the change is below 1e-7).
    pub fn undistort(&self, d: Vec2) -> Vec2 {
        let mut n = d;
        for _ in 0..20 {
            let back = self.distort(n);
            let next = n + (d - back);
            let step = (next - n).norm();
            n = next;
            if step < 1e-7 {
                break;
            }
        }
        n
    }

    /// True when the pixel position lies inside the image with `margin` pixels to spare.
    pub fn contains(&self, p: Vec2, margin: f32) -> bool {
        p.x >= -0.5 + margin
            && p.y >= -0.5 + margin
            && p.x <= self.width as f32 - 0.5 - margin
            && p.y <= self.height as f32 - 0.5 - margin
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixel_normalized_round_trip() {
        let mut cam = CameraModel::PAPER_FORWARD;
        let p = Vec2::new(100.25, 400.5);
        let n = cam.pixel_to_normalized(p);
        assert!((cam.normalized_to_pixel(n) - p).norm() < 1e-4);
        cam.distortion = Distortion { k1: -0.2, k2: 0.05, p1: 0.001, p2: -0.0005, k3: 0.0 };
        let n = cam.pixel_to_normalized(p);
        assert!((cam.normalized_to_pixel(n) - p).norm() < 1e-3);
    }
}
