//! Lens distortion for the forward camera (Brown-Conrady: `k1 k2 p1 p2 k3`, as the calibration formats give
//! it), by the way simulators usually render it: an ideal pinhole image of the scene rendered first, twice as
//! fine and wide enough to hold every ray the lens takes in, then resampled into the distorted image. Each
//! pixel of the distorted image is the mean of four samples at +-1/4 pixel (its area, as the pinhole renderer's
//! exact coverage gives it), each a bilinear read of the fine image at the undistorted position
//! (`CameraModel::pixel_to_normalized`, vision-core's own inverse of the distortion), in linear light. Blur and
//! the sensor (clipping, tone curve, noise, quantisation, `super::sensor`) are applied after, in the distorted
//! image, as a camera would.
use super::forward::{ForwardRenderer, RenderSettings};
use crate::scenario::Scenario;
use anyhow::{Result, bail};
use geometry::{Mat3, Vec2, Vec3};
use rayon::prelude::*;

/// How much finer than the distorted image the pinhole image is (per axis).
const SUPERSAMPLE: f64 = 2.0;

/// One bilinear sample of the pinhole image: the index of its top-left value and the weights across.
#[derive(Clone, Copy)]
struct Sample {
    /// `3 (y0 w + x0)`, the first of the four pixels' values (interleaved RGB).
    at: u32,
    ax: f32,
    ay: f32,
}

/// The pinhole renderer behind a distorted camera and where each distorted pixel's samples fall in it.
pub(super) struct Lens {
    source: ForwardRenderer,
    /// Per distorted pixel, row by row: its four samples in the pinhole image.
    map: Vec<[Sample; 4]>,
    /// The distorted image's width.
    width: usize,
}

impl Lens {
    /// The lens of the scenario's forward camera; `None` for an ideal pinhole (no distortion).
    pub(super) fn new(s: &Scenario) -> Result<Option<Self>> {
        let c = &s.forward_camera;
        if c.distortion.iter().all(|&d| d == 0.0) {
            return Ok(None);
        }
        let camera = s.forward_camera_model();
        let (w, h) = (c.width_px as usize, c.height_px as usize);
        let offsets = [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)];
        let mut normalized: Vec<[f32; 8]> = Vec::with_capacity(w * h);
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for v in 0..h {
            for u in 0..w {
                let mut px = [0.0f32; 8];
                for (k, (du, dv)) in offsets.iter().enumerate() {
                    let n = camera.pixel_to_normalized(Vec2::new(u as f32 + du, v as f32 + dv));
                    if !(n.x.is_finite() && n.y.is_finite()) {
                        bail!(
                            "forward_camera.distortion {:?}: pixel ({u}, {v}) has no undistorted direction (the \
                             model folds over inside the image)",
                            c.distortion
                        );
                    }
                    (px[2 * k], px[2 * k + 1]) = (n.x, n.y);
                    lo = [lo[0].min(n.x), lo[1].min(n.y)];
                    hi = [hi[0].max(n.x), hi[1].max(n.y)];
                }
                normalized.push(px);
            }
        }
        // The pinhole camera: focal lengths SUPERSAMPLE times the lens's, the image wide enough for every
        // sample with two pixels to spare.
        let (fx, fy) = (c.fx_px * SUPERSAMPLE, c.fy_px * SUPERSAMPLE);
        let cx = -(lo[0] as f64) * fx + 2.0;
        let cy = -(lo[1] as f64) * fy + 2.0;
        let sw = ((hi[0] - lo[0]) as f64 * fx + 5.0).ceil();
        let sh = ((hi[1] - lo[1]) as f64 * fy + 5.0).ceil();
        if sw * sh > 64e6 {
            bail!(
                "forward_camera.distortion {:?}: the lens takes in a field of view too wide to render ({sw} x {sh} \
                 pinhole pixels)",
                c.distortion
            );
        }
        let mut pinhole = s.clone();
        let pc = &mut pinhole.forward_camera;
        (pc.width_px, pc.height_px) = (sw as _, sh as _);
        (pc.fx_px, pc.fy_px, pc.cx_px, pc.cy_px) = (fx, fy, cx, cy);
        pc.distortion = [0.0; 5];
        // Vignetting and compression happen in the distorted image (the outer renderer); the auto exposure
        // is the source's, once.
        (pc.vignetting, pc.jpeg_quality, pc.exposure_time_s) = (0.0, 0, 0.0);
        // Its rows are SUPERSAMPLE times finer: the same readout time over them.
        pc.line_delay_s = c.line_delay_s / SUPERSAMPLE;
        let source = ForwardRenderer::new(&pinhole)?;
        let (fx, fy, cx, cy) = (fx as f32, fy as f32, cx as f32, cy as f32);
        let (sw, sh) = source.size();
        // Every sample lies at least two pixels inside the pinhole image (its size above), so its four
        // neighbours are inside too; the clamps only guard the arithmetic.
        let sample = |x: f32, y: f32| {
            let (x0, y0) = (x.floor().clamp(0.0, sw as f32 - 2.0), y.floor().clamp(0.0, sh as f32 - 2.0));
            Sample { at: (3 * (y0 as usize * sw + x0 as usize)) as u32, ax: x - x0, ay: y - y0 }
        };
        let map = normalized
            .into_iter()
            .map(|n| [0, 1, 2, 3].map(|k| sample(n[2 * k] * fx + cx, n[2 * k + 1] * fy + cy)))
            .collect();
        Ok(Some(Self { source, map, width: w }))
    }

    /// The distorted image's linear values (3 per pixel, on the 0-255 scale, before blur, the sensor's
    /// response and noise), `tau` seconds after the frame's time: the pinhole image's linear values, resampled.
    /// The pinhole source keeps the scenario's rolling shutter, timed by its own rows: an approximation (its
    /// rows are the undistorted ones), exact without distortion.
    pub(super) fn render_linear(
        &self,
        r_wc: &Mat3,
        center: Vec3,
        settings: &RenderSettings,
        tau: f64,
    ) -> Vec<f32> {
        let src = self.source.linear_image_at(r_wc, center, settings, tau);
        let row = 3 * self.source.size().0;
        let mut out = vec![0.0f32; 3 * self.map.len()];
        // Rows on the thread pool (each output value is the same sum whatever the threads).
        out.par_chunks_mut(3 * self.width).zip(self.map.par_chunks(self.width)).for_each(|(o, m)| {
            for (px, samples) in o.chunks_exact_mut(3).zip(m) {
                let mut acc = [0.0f32; 3];
                for s in samples {
                    let i = s.at as usize;
                    let (top, bottom) = (&src[i..i + 6], &src[i + row..i + row + 6]);
                    for ch in 0..3 {
                        let t = top[ch] + s.ax * (top[3 + ch] - top[ch]);
                        let b = bottom[ch] + s.ax * (bottom[3 + ch] - bottom[ch]);
                        acc[ch] += t + s.ay * (b - t);
                    }
                }
                px.copy_from_slice(&acc.map(|a| a * 0.25));
            }
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use crate::Scenario;
    use crate::render::ForwardRenderer;
    use crate::vision::GroundVision;
    use geometry::frames::Attitude;
    use geometry::{Vec2, Vec3, deg};

    #[test]
    fn the_line_corners_appear_where_the_lens_puts_them() {
        // Through a wide-angle lens the line's corners are detected where the distortion model takes their
        // pinhole projections (0.3 px), and they are far (pixels) from the pinhole positions near the sides.
        let mut s = Scenario::paper();
        s.forward_camera.distortion = [-0.3, 0.08, 0.0005, -0.0003, 0.0];
        let renderer = ForwardRenderer::new(&s).unwrap();
        let camera = s.forward_camera_model();
        let mut vision = GroundVision::new(&s);
        let mount = s.forward_camera_mount();
        let target = s.line_target();
        let att = Attitude::new(deg(1.0), deg(-2.0), deg(3.0));
        let r_wc = att.world_from_body().mul_mat(&mount.body_from_camera);
        let centre = Vec3::new(1.15, 1.6, 0.85);
        let mut settings = renderer.default_settings();
        settings.seed = 4;
        let img = renderer.render(&r_wc, centre, &settings);
        let obs = vision.detect(&img).expect("the line through the lens");
        assert_eq!(obs.real_corners(), 4);
        let r_cw = r_wc.transpose();
        let mut farthest = 0.0f32;
        for (c, got) in vision_core::Corner::ALL.iter().zip(obs.corners_px(&camera)) {
            let p = r_cw.mul_vec(target.corner(*c) - centre);
            let n = Vec2::new(p.x / p.z, p.y / p.z);
            let want = camera.normalized_to_pixel(n);
            let pinhole = Vec2::new(camera.fx * n.x + camera.cx, camera.fy * n.y + camera.cy);
            let got = got.unwrap();
            assert!((got - want).norm() < 0.3, "{c:?}: detected {got:?}, through the lens {want:?}");
            farthest = farthest.max((want - pinhole).norm());
        }
        assert!(farthest > 5.0, "the lens moves a corner by {farthest} px only");
    }
}
