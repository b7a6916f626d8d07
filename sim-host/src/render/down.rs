//! The downward camera: a grey pinhole camera looking at the textured floor (plane `z = 0`), for optical flow.
//!
//! Image formation, per pixel: the ray through the pixel centre hits the floor; the floor's albedo times its
//! texture (the same procedural concrete the forward camera sees) is sampled with trilinear filtering from a
//! mip pyramid chosen by the pixel's footprint on the floor (so fine texture does not alias into flicker); the
//! scene's light gain and gradient and the lens's vignetting scale it; the exposure integrates `K` sub-frames
//! spread over the exposure time, at poses extrapolated with the vehicle's velocity and angular rate (motion
//! blur, `K` chosen so that sub-frames are at most half a pixel apart); then the sensor (`super::sensor`):
//! clipping at full scale, the tone curve (`down_camera.response`, linear by default), Gaussian noise and 8-bit
//! quantisation. Everything is a pure function of the scene, the motion and the frame's seed.
use super::forward::{MAGIC, floor_f, noise_buffer};
use super::texture::Texture;
use crate::imageio::GrayImage;
use crate::rng::splitmix64;
use crate::scenario::Scenario;
use anyhow::{Result, bail};

/// The floor texture's finest texel (m): the same as the forward renderer's, so both cameras see one floor.
const TEXEL_M: f64 = 0.004;
/// Mip levels (texels 4, 8, 16, 32, 64 mm).
const MIPS: usize = 5;
/// Texels per pixel footprint at the chosen level: above 1, so that the texture (bilinear between texels) is
/// smoother than the pixel grid; with the optics blur this keeps the image nearly band-limited.
const LOD_BIAS: f64 = 1.4;
/// Half width of the band around a level boundary where two levels are blended: elsewhere one level is
/// sampled (half the cost), and the image still changes continuously with the altitude.
const BLEND_BAND: f64 = 0.15;
/// Standard-normal noise is stored as `round(32 n)` in an `i8`.
const NOISE_SCALE: f32 = 32.0;
/// Most sub-frames per exposure.
const MAX_SUBFRAMES: usize = 8;

/// Where the camera is and how it moves during the exposure (world frame, f64).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DownPose {
    /// World-from-camera rotation at mid-exposure.
    pub r_wc: [[f64; 3]; 3],
    /// Camera centre at mid-exposure (m).
    pub center: [f64; 3],
    /// Velocity of the camera centre (m/s).
    pub velocity: [f64; 3],
    /// Angular velocity (world frame, rad/s).
    pub omega_world: [f64; 3],
}

impl DownPose {
    /// A camera at rest.
    pub fn still(r_wc: [[f64; 3]; 3], center: [f64; 3]) -> Self {
        Self { r_wc, center, velocity: [0.0; 3], omega_world: [0.0; 3] }
    }

    /// The pose `tau` seconds from mid-exposure (constant velocity and angular rate).
    pub fn at(&self, tau: f64) -> ([[f64; 3]; 3], [f64; 3]) {
        let c = [0, 1, 2].map(|k| self.center[k] + self.velocity[k] * tau);
        let rot = rotvec_to_mat(self.omega_world.map(|w| w * tau));
        (mat_mul(&rot, &self.r_wc), c)
    }
}

/// Per-frame settings that tests and flights vary around the scenario's values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DownSettings {
    /// Illumination gain (replaces the scene's).
    pub light_gain: f64,
    /// Sensor noise (grey levels, 1 sigma).
    pub noise_sigma: f64,
    /// Exposure time (s).
    pub exposure_time_s: f64,
    /// Optical blur (px, Gaussian sigma; a 5-tap kernel, so up to about 1.5 px).
    pub blur_sigma_px: f64,
    /// Seed of this frame's sensor noise.
    pub seed: u64,
}

struct Mip {
    w: usize,
    h: usize,
    inv_texel: f64,
    data: Vec<f32>,
}

/// Renders the downward camera's view.
pub struct DownRenderer {
    width: usize,
    height: usize,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    origin: [f64; 2],
    mips: Vec<Mip>,
    albedo: f32,
    exposure: f32,
    gradient_x: f32,
    light_center_x: f32,
    vignette: Vec<f32>,
    /// Clipping, tone curve and quantisation (`super::sensor`).
    response: super::sensor::Response,
    noise: Vec<i8>,
    defaults: DownSettings,
}

fn mat_mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

/// Rodrigues' formula.
fn rotvec_to_mat(r: [f64; 3]) -> [[f64; 3]; 3] {
    let th = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    if th < 1e-12 {
        return [[1.0, -r[2], r[1]], [r[2], 1.0, -r[0]], [-r[1], r[0], 1.0]];
    }
    let k = r.map(|v| v / th);
    let (s, c) = th.sin_cos();
    let v = 1.0 - c;
    [
        [c + k[0] * k[0] * v, k[0] * k[1] * v - k[2] * s, k[0] * k[2] * v + k[1] * s],
        [k[1] * k[0] * v + k[2] * s, c + k[1] * k[1] * v, k[1] * k[2] * v - k[0] * s],
        [k[2] * k[0] * v - k[1] * s, k[2] * k[1] * v + k[0] * s, c + k[2] * k[2] * v],
    ]
}

impl DownRenderer {
    /// Prepares the floor of a scenario (bakes the texture and its mip pyramid).
    pub fn new(s: &Scenario) -> Result<Self> {
        let c = &s.down_camera;
        let sc = &s.scene;
        if c.width_px < 2 || c.height_px < 2 {
            bail!("down_camera: the image must be at least 2x2");
        }
        // The same floor as the forward renderer: same kind, contrast, seed, origin and texel.
        let x0 = sc.line_x_start_m - 3.0;
        let xs = sc.line_x_end_m - sc.line_x_start_m + 6.0;
        let base = Texture::bake(
            sc.floor_texture.kind(),
            sc.floor_texture_contrast,
            sc.texture_seed ^ 0xF100,
            [x0, 0.0],
            [xs, 4.0],
            TEXEL_M,
        );
        let (w0, h0) = base.dims();
        let mut mips = vec![Mip { w: w0, h: h0, inv_texel: 1.0 / TEXEL_M, data: base.texels().to_vec() }];
        for l in 1..MIPS {
            let p = &mips[l - 1];
            let (w, h) = ((p.w / 2).max(1), (p.h / 2).max(1));
            let mut data = vec![0.0f32; w * h];
            for y in 0..h {
                for x in 0..w {
                    let at = |xx: usize, yy: usize| p.data[yy.min(p.h - 1) * p.w + xx.min(p.w - 1)];
                    data[y * w + x] = 0.25
                        * (at(2 * x, 2 * y)
                            + at(2 * x + 1, 2 * y)
                            + at(2 * x, 2 * y + 1)
                            + at(2 * x + 1, 2 * y + 1));
                }
            }
            let inv_texel = p.inv_texel * 0.5;
            mips.push(Mip { w, h, inv_texel, data });
        }
        let (w, h) = (c.width_px as usize, c.height_px as usize);
        // Vignetting: a quadratic fall-off in the distance from the principal point, `vignetting` at the corners.
        let r2max = (c.cx_px.max(w as f64 - 1.0 - c.cx_px) / c.fx_px).powi(2)
            + (c.cy_px.max(h as f64 - 1.0 - c.cy_px) / c.fy_px).powi(2);
        let mut vignette = vec![1.0f32; w * h];
        for v in 0..h {
            for u in 0..w {
                let (xn, yn) = ((u as f64 - c.cx_px) / c.fx_px, (v as f64 - c.cy_px) / c.fy_px);
                vignette[v * w + u] = (1.0 - c.vignetting * (xn * xn + yn * yn) / r2max) as f32;
            }
        }
        let a = sc.floor_albedo_rgb;
        Ok(Self {
            width: w,
            height: h,
            fx: c.fx_px,
            fy: c.fy_px,
            cx: c.cx_px,
            cy: c.cy_px,
            origin: [x0, 0.0],
            mips,
            albedo: (0.299 * a[0] + 0.587 * a[1] + 0.114 * a[2]) as f32,
            exposure: c.exposure as f32,
            gradient_x: sc.light_gradient_per_m[0] as f32,
            light_center_x: (0.5 * (sc.line_x_start_m + sc.line_x_end_m)) as f32,
            vignette,
            response: super::sensor::Response::new(c.response),
            noise: noise_buffer(w * h),
            defaults: DownSettings {
                light_gain: sc.light_gain,
                noise_sigma: c.noise_sigma,
                exposure_time_s: c.exposure_time_s,
                blur_sigma_px: c.blur_sigma_px,
                seed: 0,
            },
        })
    }

    /// The scenario's settings (with seed 0).
    pub fn default_settings(&self) -> DownSettings {
        self.defaults
    }

    /// Image size (width, height).
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Sub-frames needed so that consecutive ones are at most half a pixel apart in the image.
    fn subframes(&self, pose: &DownPose, exposure_s: f64) -> usize {
        let height = pose.center[2].max(0.02);
        let speed = pose.velocity.iter().map(|v| v * v).sum::<f64>().sqrt();
        let rate = pose.omega_world.iter().map(|v| v * v).sum::<f64>().sqrt();
        // Translation moves the image by f v / h; rotation by up to f w (1 + tan^2 of the half field of view).
        let f = self.fx.max(self.fy);
        let px = exposure_s * f * (speed / height + 1.5 * rate);
        ((px / 0.5).ceil() as usize).clamp(1, MAX_SUBFRAMES)
    }

    /// Renders one frame.
    pub fn render(&self, pose: &DownPose, settings: &DownSettings) -> GrayImage {
        let (w, h) = (self.width, self.height);
        let k = self.subframes(pose, settings.exposure_time_s);
        let mut acc = vec![0.0f32; w * h];
        for s in 0..k {
            let tau = ((s as f64 + 0.5) / k as f64 - 0.5) * settings.exposure_time_s;
            let (r, c) = pose.at(tau);
            self.accumulate(&r, c, settings.light_gain as f32 / k as f32, &mut acc);
        }
        if settings.blur_sigma_px > 0.0 {
            blur5(&mut acc, w, h, settings.blur_sigma_px);
        }
        let scale = 255.0 * self.exposure * self.albedo;
        for (a, vg) in acc.iter_mut().zip(&self.vignette) {
            *a = scale * *a * vg;
        }
        let sigma = settings.noise_sigma as f32 / NOISE_SCALE;
        let mut img = GrayImage::new(w, h);
        self.response.finish(&acc, self.noise_block(settings.seed), sigma, &mut img.data);
        img
    }

    /// Adds `gain` times the light-weighted floor texture seen from `(r_wc, c)` to `acc`.
    fn accumulate(&self, r: &[[f64; 3]; 3], c: [f64; 3], gain: f32, acc: &mut [f32]) {
        let (w, h) = (self.width, self.height);
        // Ray direction of pixel (u, v): d = R (x_n, y_n, 1) = d0 + u du + v dv.
        let col = |k: usize| [r[0][k], r[1][k], r[2][k]];
        let (ex, ey, ez) = (col(0), col(1), col(2));
        let du = ex.map(|v| v / self.fx);
        let dv = ey.map(|v| v / self.fy);
        let d0 = [0, 1, 2].map(|i| ez[i] - self.cx * du[i] - self.cy * dv[i]);
        // Mip level from the footprint of a pixel at the image centre (m per px); two levels are blended only
        // near the boundary between them.
        let dz_centre = ez[2];
        let range = if dz_centre < -1e-3 { c[2] / -dz_centre } else { 1e3 };
        let footprint = range / self.fx.min(self.fy);
        let lod = (LOD_BIAS * footprint / TEXEL_M).max(1.0).log2().min((MIPS - 1) as f64);
        let l0 = (lod.floor() as usize).min(MIPS - 1);
        let l1 = (l0 + 1).min(MIPS - 1);
        let frac = lod - l0 as f64;
        let t = (((frac - (0.5 - BLEND_BAND)) / (2.0 * BLEND_BAND)).clamp(0.0, 1.0)) as f32;
        // One level when the blend weight is 0 or 1.
        let (l0, t) = if t >= 1.0 { (l1, 0.0) } else { (l0, t) };
        let l1 = if t > 0.0 { l1 } else { l0 };
        let (m0, m1) = (&self.mips[l0], &self.mips[l1]);
        // Per pixel in f32 relative to the camera's ground point (small numbers, exact enough), with the
        // texture coordinates offset by the camera's own (the f64 part is per frame).
        let (ox, oy) = (c[0] - self.origin[0], c[1] - self.origin[1]);
        let cz = c[2] as f32;
        let (du, dv, d0) = (du.map(|v| v as f32), dv.map(|v| v as f32), d0.map(|v| v as f32));
        let s0 = Sampler::new(m0, ox, oy);
        let s1 = Sampler::new(m1, ox, oy);
        let (gx, lcx) = (self.gradient_x, (self.light_center_x as f64 - c[0]) as f32);
        // Row buffers: floor coordinates, then per mip level the texel index and weights (vectorisable
        // passes around the one gather).
        let mut xs = vec![0.0f32; w];
        let mut ys = vec![0.0f32; w];
        let mut flat = vec![false; w];
        let mut t0 = vec![0.0f32; w];
        let mut t1 = vec![0.0f32; w];
        let mut scratch = SampleRow::new(w);
        for v in 0..h {
            let vf = v as f32;
            let dr = [d0[0] + vf * dv[0], d0[1] + vf * dv[1], d0[2] + vf * dv[2]];
            for (u, ((x, y), f)) in xs.iter_mut().zip(ys.iter_mut()).zip(flat.iter_mut()).enumerate() {
                let uf = u as f32;
                let (dx, dy, dz) = (dr[0] + uf * du[0], dr[1] + uf * du[1], dr[2] + uf * du[2]);
                // At or above the horizon: a far point (the texture clamps), marked to show the mean floor.
                *f = dz >= -1e-6;
                let tt = -cz / dz.min(-1e-6);
                (*x, *y) = (tt * dx, tt * dy);
            }
            s0.sample_row(&xs, &ys, &mut scratch, &mut t0);
            if t > 0.0 {
                s1.sample_row(&xs, &ys, &mut scratch, &mut t1);
            } else {
                t1.copy_from_slice(&t0);
            }
            let row = &mut acc[v * w..(v + 1) * w];
            for ((((a, &x), &f), &p0), &p1) in row.iter_mut().zip(&xs).zip(&flat).zip(&t0).zip(&t1) {
                let tex = if f { 1.0 } else { p0 + t * (p1 - p0) };
                let light = if f { 1.0 } else { (1.0 + gx * (x - lcx)).max(0.0) };
                *a += gain * tex * light;
            }
        }
    }

    /// This frame's block of standard-normal noise (scaled by `NOISE_SCALE`).
    fn noise_block(&self, seed: u64) -> &[i8] {
        let need = self.width * self.height;
        let mut s = seed ^ 0x5A5A_A5A5_0DDB_A110;
        let off = (splitmix64(&mut s) % (self.noise.len() - need) as u64) as usize;
        &self.noise[off..off + need]
    }
}

/// Bilinear sampling of one mip level around a camera's foot point: coordinates relative to the foot (m,
/// f32) are turned into texel coordinates with a per-frame offset, then sampled without calls to `floor`
/// (a shift keeps the value positive for truncation) and with the index clamped to the texture.
struct Sampler<'a> {
    m: &'a Mip,
    inv: f32,
    /// Texel coordinate of the foot point, plus the positive shift, minus the half-texel.
    bx: f32,
    by: f32,
    xmax: i32,
    ymax: i32,
}

/// Separable 5-tap Gaussian blur (edges clamped): the lens and the pixel's area, which keep the image nearly
/// band-limited, as sub-pixel tracking assumes of a real camera.
fn blur5(img: &mut [f32], w: usize, h: usize, sigma: f64) {
    let g = |i: f64| (-i * i / (2.0 * sigma * sigma)).exp();
    let sum = g(0.0) + 2.0 * g(1.0) + 2.0 * g(2.0);
    let k = [g(0.0) / sum, g(1.0) / sum, g(2.0) / sum].map(|v| v as f32);
    let mut tmp = vec![0.0f32; w * h];
    let cl = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    for y in 0..h {
        let r = &img[y * w..(y + 1) * w];
        let o = &mut tmp[y * w..(y + 1) * w];
        // Interior without clamping (vectorisable), then the two columns at each edge.
        for (o, t) in o[2..w - 2].iter_mut().zip(r.windows(5)) {
            *o = k[0] * t[2] + k[1] * (t[1] + t[3]) + k[2] * (t[0] + t[4]);
        }
        for x in [0, 1, w - 2, w - 1] {
            let xi = x as isize;
            o[x] = k[0] * r[x]
                + k[1] * (r[cl(xi - 1, w)] + r[cl(xi + 1, w)])
                + k[2] * (r[cl(xi - 2, w)] + r[cl(xi + 2, w)]);
        }
    }
    for y in 0..h {
        let yi = y as isize;
        let (u2, u1, d1, d2) = (cl(yi - 2, h), cl(yi - 1, h), cl(yi + 1, h), cl(yi + 2, h));
        let (r_u2, r_u1, r_c) = (&tmp[u2 * w..u2 * w + w], &tmp[u1 * w..u1 * w + w], &tmp[y * w..y * w + w]);
        let (r_d1, r_d2) = (&tmp[d1 * w..d1 * w + w], &tmp[d2 * w..d2 * w + w]);
        for (x, o) in img[y * w..(y + 1) * w].iter_mut().enumerate() {
            *o = k[0] * r_c[x] + k[1] * (r_u1[x] + r_d1[x]) + k[2] * (r_u2[x] + r_d2[x]);
        }
    }
}

/// Per-row scratch of [`Sampler::sample_row`].
struct SampleRow {
    idx: Vec<u32>,
    tx: Vec<f32>,
    ty: Vec<f32>,
}

impl SampleRow {
    fn new(w: usize) -> Self {
        Self { idx: vec![0; w], tx: vec![0.0; w], ty: vec![0.0; w] }
    }
}

/// Keeps texel coordinates positive so that truncation is `floor`.
const SHIFT: f32 = 4096.0;

impl<'a> Sampler<'a> {
    fn new(m: &'a Mip, ox: f64, oy: f64) -> Self {
        Self {
            m,
            inv: m.inv_texel as f32,
            bx: (ox * m.inv_texel - 0.5 + SHIFT as f64) as f32,
            by: (oy * m.inv_texel - 0.5 + SHIFT as f64) as f32,
            xmax: m.w as i32 - 2,
            ymax: m.h as i32 - 2,
        }
    }

    /// Samples a row of points into `out`.
    // `max` then `min` (not `clamp`) maps NaN to the lower bound.
    #[allow(clippy::manual_clamp)]
    fn sample_row(&self, xs: &[f32], ys: &[f32], tmp: &mut SampleRow, out: &mut [f32]) {
        let w = self.m.w;
        // Pass 1: texel indices and weights, all in f32 (exact: the textures have fewer than 2^24 texels),
        // vectorisable.
        let (wf, xmax, ymax) = (w as f32, self.xmax as f32, self.ymax as f32);
        for ((((&x, &y), idx), tx), ty) in
            xs.iter().zip(ys).zip(tmp.idx.iter_mut()).zip(tmp.tx.iter_mut()).zip(tmp.ty.iter_mut())
        {
            // Branch-free float-to-integer steps (see `forward::floor_f`): Rust's saturating `as` casts do
            // not vectorise here.
            let fx = (x * self.inv + self.bx).max(0.0).min(4.0e6);
            let fy = (y * self.inv + self.by).max(0.0).min(4.0e6);
            let (xf, yf) = (floor_f(fx), floor_f(fy));
            *tx = fx - xf;
            *ty = fy - yf;
            let xi = (xf - SHIFT).max(0.0).min(xmax);
            let yi = (yf - SHIFT).max(0.0).min(ymax);
            *idx = (yi * wf + xi + MAGIC).to_bits() & 0x007F_FFFF;
        }
        // Pass 2: the gather and the blend.
        let d = &self.m.data;
        for (((o, &i), &tx), &ty) in out.iter_mut().zip(&tmp.idx).zip(&tmp.tx).zip(&tmp.ty) {
            let i = i as usize;
            let q = &d[i..i + w + 2];
            let (a, b, c, e) = (q[0], q[1], q[w], q[w + 1]);
            let top = a + tx * (b - a);
            let bot = c + tx * (e - c);
            *o = top + ty * (bot - top);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::frames::{Attitude, BODY_FROM_DOWN_CAMERA};

    fn level_pose(x: f64, y: f64, z: f64) -> DownPose {
        let r = Attitude::new(0.0, 0.0, 0.0).world_from_body().mul_mat(&BODY_FROM_DOWN_CAMERA);
        DownPose::still(r.m.map(|row| row.map(|v| v as f64)), [x, y, z])
    }

    #[test]
    fn the_floor_is_textured_and_moves_with_the_camera() {
        let s = Scenario::paper();
        let r = DownRenderer::new(&s).unwrap();
        let mut set = r.default_settings();
        set.noise_sigma = 0.0;
        let a = r.render(&level_pose(1.0, 1.3, 0.8), &set);
        let mean = a.data.iter().map(|&v| v as f64).sum::<f64>() / a.data.len() as f64;
        let var = a.data.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / a.data.len() as f64;
        assert!(mean > 40.0 && mean < 200.0 && var.sqrt() > 8.0, "mean {mean}, sd {}", var.sqrt());
        // Moving the camera by one pixel's footprint along world x moves the image by one pixel. World x is
        // the body's left (y_B) at zero yaw; the camera's x is -y_B: the content shifts toward +u.
        let fp = 0.8 / s.down_camera.fx_px;
        let b = r.render(&level_pose(1.0 + 3.0 * fp, 1.3, 0.8), &set);
        let w = a.width;
        let mut err_shift = 0.0;
        let mut err_same = 0.0;
        for v in 10..a.height - 10 {
            for u in 10..w - 10 {
                err_shift += (b.data[v * w + u] as f64 - a.data[v * w + u - 3] as f64).abs();
                err_same += (b.data[v * w + u] as f64 - a.data[v * w + u] as f64).abs();
            }
        }
        assert!(err_shift < 0.25 * err_same, "shifted {err_shift} vs unshifted {err_same}");
    }

    #[test]
    fn a_blank_floor_is_flat_and_motion_blurs() {
        let mut s = Scenario::paper();
        s.scene.floor_texture_contrast = 0.0;
        let r = DownRenderer::new(&s).unwrap();
        let mut set = r.default_settings();
        set.noise_sigma = 0.0;
        let img = r.render(&level_pose(1.0, 1.3, 0.8), &set);
        let centre = img.data[60 * img.width + 80];
        assert!(img.data.iter().all(|&v| v <= centre), "vignetting only darkens towards the corners");
        // Motion blur: a frame taken while moving is the mean of still frames over the exposure.
        let s = Scenario::paper();
        let r = DownRenderer::new(&s).unwrap();
        let mut moving = level_pose(1.0, 1.3, 0.8);
        moving.velocity = [2.0, 0.0, 0.0];
        set.exposure_time_s = 0.01;
        let blurred = r.render(&moving, &set);
        let k = r.subframes(&moving, set.exposure_time_s);
        assert!(k > 4, "a 3.5 px motion needs sub-frames: {k}");
        let mut mean = vec![0.0f64; blurred.data.len()];
        for i in 0..k {
            let tau = ((i as f64 + 0.5) / k as f64 - 0.5) * set.exposure_time_s;
            let still = r.render(&level_pose(1.0 + 2.0 * tau, 1.3, 0.8), &set);
            for (m, v) in mean.iter_mut().zip(&still.data) {
                *m += *v as f64 / k as f64;
            }
        }
        let sharp = r.render(&level_pose(1.0, 1.3, 0.8), &set);
        let diff = |img: &GrayImage| {
            img.data.iter().zip(&mean).map(|(a, b)| (*a as f64 - b).abs()).fold(0.0, f64::max)
        };
        assert!(diff(&blurred) <= 1.0, "blurred frame vs mean of still frames: {}", diff(&blurred));
        assert!(diff(&sharp) > 5.0, "the sharp frame differs from the blurred one: {}", diff(&sharp));
    }
}
