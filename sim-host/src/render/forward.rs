//! The forward camera: a pinhole camera looking at the wall (plane `y = 0`) with the painted line, above the
//! floor (plane `z = 0`).
//!
//! Image formation, per pixel: the ray through the pixel centre hits the wall or the floor; the surface
//! albedo (times its texture) is lit by the scene's gain and gradient; the line's paint covers the pixel by
//! its exact area (the line's image is a convex polygon, clipped to the near plane), so edges are
//! box-filter anti-aliased; exposure; optional Gaussian blur; then the sensor (`super::sensor`): clipping per
//! channel at full scale, the tone curve (sRGB by default), Gaussian noise and 8-bit quantisation.
//! Everything is a pure function of the scene, the pose and the frame's seed.
use super::polygon::{Poly, row_coverage};
use super::sensor::{Response, gaussian_blur_rgb};
use super::texture::{Texture, TextureKind};
use crate::imageio::RgbImage;
use crate::rng::{NormalTable, splitmix64};
use crate::scenario::Scenario;
use anyhow::Result;
use geometry::{Mat3, Vec3};
use rayon::prelude::*;

/// Rows per band when a frame is rendered on several threads (60 bands of a 480-row frame: small enough to
/// balance two to eight threads, large enough to be worth a task; the scratch buffers are made once per task
/// the pool splits off, not per band).
const ROW_BAND: usize = 8;

/// The per-row working buffers of [`ForwardRenderer::render`], one set per band of rows.
struct RowScratch {
    cov: Vec<f32>,
    gain: Vec<f32>,
    idx: Vec<i32>,
    planes: [Vec<f32>; 3],
    qplanes: [Vec<u8>; 3],
    on_wall: Vec<f32>,
    xs: Vec<f32>,
    bs: Vec<f32>,
    tex: Vec<f32>,
    lit: Vec<f32>,
    cov_sum: Vec<f32>,
    paint: [Vec<f32>; 3],
}

impl RowScratch {
    /// No buffers (a placeholder while a row holds them; allocates nothing).
    fn empty() -> Self {
        Self::new(0)
    }

    fn new(w: usize) -> Self {
        let f = || vec![0.0f32; w];
        Self {
            cov: f(),
            gain: f(),
            idx: vec![0i32; w],
            planes: [f(), f(), f()],
            qplanes: [vec![0u8; w], vec![0u8; w], vec![0u8; w]],
            on_wall: f(),
            xs: f(),
            bs: f(),
            tex: f(),
            lit: f(),
            cov_sum: f(),
            paint: [f(), f(), f()],
        }
    }
}

/// Per-frame settings that tests and flights vary around the scenario's values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Illumination gain (replaces the scene's).
    pub light_gain: f64,
    /// Relative change of the illumination per metre along the wall's x and z.
    pub light_gradient_per_m: [f64; 2],
    /// Sensor noise (grey levels, 1 sigma).
    pub noise_sigma: f64,
    /// Optical blur (px, Gaussian sigma).
    pub blur_sigma_px: f64,
    /// This frame's exposure relative to the camera's (times the auto exposure's factor when the scenario's
    /// `exposure_step` is not zero).
    pub exposure_gain: f64,
    /// The camera centre's velocity (world, m/s) and the camera's angular velocity (world frame, rad/s) at
    /// the frame's time: with the scenario's `exposure_time_s` they blur the frame, with its `line_delay_s`
    /// each row sees the scene from where the camera is when that row is exposed (a rolling shutter).
    pub velocity_m_s: [f64; 3],
    /// See `velocity_m_s`.
    pub rates_rad_s: [f64; 3],
    /// Seed of this frame's sensor noise (and auto exposure).
    pub seed: u64,
}

/// Renders the forward camera's view.
pub struct ForwardRenderer {
    width: usize,
    height: usize,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    /// Convex polygons painted on the wall: vertices `(x, z)` and albedo. The line comes first.
    painted: Vec<(Vec<[f64; 2]>, [f32; 3])>,
    line_center: [f64; 3],
    wall_albedo: [f32; 3],
    floor_albedo: [f32; 3],
    exposure: f32,
    stack: TextureStack,
    noise: Vec<i8>,
    defaults: RenderSettings,
    /// The lens, when the camera's distortion is not zero (`super::lens`).
    lens: Option<Box<super::lens::Lens>>,
    /// Clipping, tone curve and quantisation (`super::sensor`).
    response: Response,
    /// Per pixel, the lens's light fall-off (None without vignetting).
    vignette: Option<Vec<f32>>,
    /// Auto exposure's relative step (`forward_camera.exposure_step`).
    exposure_step: f64,
    /// JPEG quality of the delivered frames (0: uncompressed).
    jpeg_quality: u8,
    /// Exposure time (s; motion blur when the camera moves).
    exposure_time_s: f64,
    /// Rolling shutter: the delay between the exposures of consecutive rows (s; 0 for a global shutter).
    line_delay_s: f64,
}

/// Where the camera is for one row (or the whole frame): the ray directions' basis, the centre and the
/// painted shapes' images with their row ranges.
struct View {
    ex: [f64; 3],
    ey: [f64; 3],
    ez: [f64; 3],
    du: [f32; 3],
    cf: [f32; 3],
    polys: Vec<(Poly, [f32; 3], i64, i64)>,
}

/// The rotation `exp([w] t)` (Rodrigues).
fn rotation_exp(w: [f64; 3], t: f64) -> [[f64; 3]; 3] {
    let v = w.map(|x| x * t);
    let th = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let k = [[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]];
    let (a, b) = if th < 1e-9 { (1.0, 0.5) } else { (th.sin() / th, (1.0 - th.cos()) / (th * th)) };
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let kk: f64 = (0..3).map(|m| k[i][m] * k[m][j]).sum();
            r[i][j] = f64::from(u8::from(i == j)) + a * k[i][j] + b * kk;
        }
    }
    r
}

/// Standard-normal noise is stored as `round(32 n)` in an `i8` (clipped at +-3.97 sigma).
const NOISE_SCALE: f32 = 32.0;

/// The wall texture (rows indexed by z) and the floor texture (rows indexed by y) stacked in one table with
/// the same texel size and x range, so a pixel's texel is one branch-free index.
struct TextureStack {
    origin_x: f32,
    inv_texel: f32,
    width_f: f32,
    wall_rows_f: f32,
    x_max: f32,
    wall_max: f32,
    floor_max: f32,
    /// Brightness multipliers times 64, as bytes (half the memory traffic of f32 or less).
    data: Vec<u8>,
}

const TEXEL_M: f64 = 0.004;
/// Pixels between exact evaluations of the perspective mapping.
const SPAN: usize = 8;

impl TextureStack {
    fn new(wall: &Texture, floor: &Texture, origin_x: f64) -> Self {
        let (w, hw) = wall.dims();
        let (wf, hf) = floor.dims();
        debug_assert_eq!(w, wf);
        let mut data = Vec::with_capacity(w * (hw + hf));
        let q = |v: &f32| (v * 64.0).round().clamp(0.0, 255.0) as u8;
        data.extend(wall.texels().iter().map(q));
        data.extend(floor.texels().iter().map(q));
        assert!(data.len() < (1 << 22), "texture table too large for the index conversion");
        Self {
            origin_x: origin_x as f32,
            inv_texel: (1.0 / TEXEL_M) as f32,
            width_f: w as f32,
            wall_rows_f: hw as f32,
            x_max: (w - 1) as f32,
            wall_max: (hw - 1) as f32,
            floor_max: (hf - 1) as f32,
            data,
        }
    }
}

/// Four frames' worth of standard-normal noise, fixed for the renderer (per-frame windows at random offsets).
pub(super) fn noise_buffer(per_frame: usize) -> Vec<i8> {
    let table = NormalTable::new();
    let mut s = 0x005E_ED0F_u64;
    let n = 4 * per_frame + 4096;
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let bits = splitmix64(&mut s);
        for k in 0..5 {
            out.push((table.get(bits >> (12 * k)) * NOISE_SCALE).round().clamp(-127.0, 127.0) as i8);
        }
    }
    out.truncate(n);
    out
}

/// Adding 2^23 to a float in `[0, 2^23)` leaves its value, rounded to the nearest integer (ties to even), in
/// the low mantissa bits: an exact, branch-free conversion that vectorises.
pub(super) const MAGIC: f32 = 8_388_608.0;
/// 1.5 * 2^23: keeps `v - 0.5 + MAGIC_FLOOR` in `[2^23, 2^24)` (unit spacing) for `-2^22 <= v - 0.5 < 2^22`.
const MAGIC_FLOOR: f32 = 12_582_912.0;

/// Index of the texel containing `v` (texel `i` spans `[i, i + 1)`), as a float, for `0 <= v < 2^22`: the
/// nearest integer to `v - 0.5`, so exactly `floor(v)` except at integer `v`, where ties go to even.
#[inline(always)]
pub(super) fn floor_f(v: f32) -> f32 {
    (v - 0.5 + MAGIC_FLOOR) - MAGIC_FLOOR
}

/// [`floor_f`] as an integer.
#[inline(always)]
fn floor_small(v: f32) -> i32 {
    ((v - 0.5 + MAGIC_FLOOR).to_bits() & 0x007F_FFFF) as i32 - (1 << 22)
}

/// Clamps to `0..=255` and rounds to the nearest grey level (ties to even). `max` first, so NaN gives 0
/// (`clamp` would keep the NaN).
#[inline(always)]
#[allow(clippy::manual_clamp)]
pub(super) fn quantise(v: f32) -> u8 {
    (v.max(0.0).min(255.0) + MAGIC).to_bits() as u8
}

fn to64(m: &Mat3) -> [[f64; 3]; 3] {
    m.m.map(|r| r.map(|v| v as f64))
}

impl ForwardRenderer {
    /// Prepares the scene of a scenario (bakes the textures).
    pub fn new(s: &Scenario) -> Result<Self> {
        let c = &s.forward_camera;
        let lens = super::lens::Lens::new(s)?.map(Box::new);
        let t = s.line_target();
        let sc = &s.scene;
        let mut painted = Vec::new();
        if sc.line_visible {
            let corners = vision_core::Corner::ALL.map(|k| {
                let p = t.corner(k);
                [p.x as f64, p.z as f64]
            });
            painted.push((corners.to_vec(), sc.line_albedo_rgb.map(|v| v as f32)));
        }
        for shape in &sc.shapes {
            let (pts, albedo) = shape.polygon();
            painted.push((pts, albedo.map(|v| v as f32)));
        }
        let lc = t.center();
        let seed = sc.texture_seed;
        // Texture extents: 3 m beyond each end of the line, the wall up to 3 m, the floor 4 m out from the
        // wall (fewer than 2^22 texels in all, see `floor_small`).
        let x0 = sc.line_x_start_m - 3.0;
        let xs = sc.line_x_end_m - sc.line_x_start_m + 6.0;
        Ok(Self {
            width: c.width_px as usize,
            height: c.height_px as usize,
            fx: c.fx_px,
            fy: c.fy_px,
            cx: c.cx_px,
            cy: c.cy_px,
            painted,
            line_center: [lc.x as f64, lc.y as f64, lc.z as f64],
            wall_albedo: sc.wall_albedo_rgb.map(|v| v as f32),
            floor_albedo: sc.floor_albedo_rgb.map(|v| v as f32),
            exposure: c.exposure as f32,
            stack: TextureStack::new(
                &Texture::bake(
                    TextureKind::Plaster,
                    sc.wall_texture_contrast,
                    seed,
                    [x0, 0.0],
                    [xs, 3.0],
                    TEXEL_M,
                ),
                &Texture::bake(
                    sc.floor_texture.kind(),
                    sc.floor_texture_contrast,
                    seed ^ 0xF100,
                    [x0, 0.0],
                    [xs, 4.0],
                    TEXEL_M,
                ),
                x0,
            ),
            noise: noise_buffer(3 * c.width_px as usize * c.height_px as usize),
            lens,
            response: Response::new(c.response),
            vignette: super::sensor::vignette(c),
            exposure_step: c.exposure_step,
            exposure_time_s: c.exposure_time_s,
            line_delay_s: c.line_delay_s,
            // Validated to 0..=100.
            jpeg_quality: c.jpeg_quality.clamp(0, 100) as u8,
            defaults: RenderSettings {
                light_gain: sc.light_gain,
                light_gradient_per_m: sc.light_gradient_per_m,
                noise_sigma: c.noise_sigma,
                blur_sigma_px: c.blur_sigma_px,
                exposure_gain: 1.0,
                velocity_m_s: [0.0; 3],
                rates_rad_s: [0.0; 3],
                seed: 0,
            },
        })
    }

    /// Image width and height (px).
    pub(super) fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The scenario's render settings (with seed 0).
    pub fn default_settings(&self) -> RenderSettings {
        self.defaults
    }

    /// Renders the view of a camera with world-from-camera rotation `r_wc` and centre `center` (world).
    pub fn render(&self, r_wc: &Mat3, center: Vec3, settings: &RenderSettings) -> RgbImage {
        let mut img = RgbImage::new(self.width, self.height);
        self.render_into(r_wc, center, settings, &mut img);
        img
    }

    /// [`Self::render`] into `img`, whose buffer is reused (every byte is written): a flight renders its
    /// frames into one buffer instead of allocating and clearing 0.9 MB per frame.
    pub fn render_into(&self, r_wc: &Mat3, center: Vec3, settings: &RenderSettings, img: &mut RgbImage) {
        if (img.width, img.height, img.data.len()) != (self.width, self.height, 3 * self.width * self.height)
        {
            *img = RgbImage::new(self.width, self.height);
        }
        let subframes = self.subframes(center, settings);
        if self.lens.is_none() && settings.blur_sigma_px <= 0.0 && subframes == 1 {
            self.rows(r_wc, center, settings, Rows::Encoded(&mut img.data));
        } else {
            // Through the lens (the resampled pinhole image), the optics' blur or the motion during the
            // exposure: the whole frame's linear values first (the mean of the sub-frames' views), then the
            // sensor.
            let view = |tau: f64| match &self.lens {
                Some(lens) => lens.render_linear(r_wc, center, settings, tau),
                None => self.linear_image_at(r_wc, center, settings, tau),
            };
            let mut linear = if subframes == 1 {
                view(0.0)
            } else {
                let t = self.exposure_time_s;
                let mut sum = vec![0.0f32; 3 * self.width * self.height];
                for k in 0..subframes {
                    let tau = ((k as f64 + 0.5) / subframes as f64 - 0.5) * t;
                    for (a, b) in sum.iter_mut().zip(view(tau)) {
                        *a += b;
                    }
                }
                let inv = 1.0 / subframes as f32;
                sum.iter_mut().for_each(|a| *a *= inv);
                sum
            };
            if let Some(v) = &self.vignette {
                for (px, g) in linear.chunks_exact_mut(3).zip(v) {
                    px.iter_mut().for_each(|c| *c *= g);
                }
            }
            if settings.blur_sigma_px > 0.0 {
                gaussian_blur_rgb(&mut linear, self.width, self.height, settings.blur_sigma_px);
            }
            let sigma = settings.noise_sigma as f32 / NOISE_SCALE;
            self.response.finish(&linear, self.noise_block(settings.seed), sigma, &mut img.data);
        }
        if self.jpeg_quality > 0 {
            *img = super::sensor::through_jpeg(img, self.jpeg_quality);
        }
    }

    /// Sub-frames of a motion-blurred exposure: enough that consecutive views are at most half a pixel apart
    /// (the image moves by about f (|v| / d + 1.5 |w|) px/s at distance d from the wall), at most 16; 1 without
    /// an exposure time or motion.
    fn subframes(&self, center: Vec3, settings: &RenderSettings) -> usize {
        let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let (speed, rate) = (norm(settings.velocity_m_s), norm(settings.rates_rad_s));
        if self.exposure_time_s <= 0.0 || speed + rate == 0.0 {
            return 1;
        }
        let d = (center.y as f64).abs().max(0.2);
        let px = self.exposure_time_s * self.fx.max(self.fy) * (speed / d + 1.5 * rate);
        ((px / 0.5).ceil() as usize).clamp(1, 16)
    }

    /// The auto exposure's factor for a frame (1 without it): uniform in `1 +- exposure_step`, drawn from the
    /// frame's seed.
    fn auto_exposure(&self, seed: u64) -> f32 {
        if self.exposure_step <= 0.0 {
            return 1.0;
        }
        let mut s = seed ^ 0xAE00_AE00_AE00_AE00;
        let u = (splitmix64(&mut s) >> 11) as f64 / (1u64 << 53) as f64;
        (1.0 + self.exposure_step * (2.0 * u - 1.0)) as f32
    }

    /// The light on each pixel (3 values per pixel, interleaved, on the 0-255 scale of the sensor's full
    /// scale), before blur, clipping, tone curve, noise and quantisation, `tau` seconds after the frame's time
    /// (rows timed by the rolling shutter from there).
    pub(super) fn linear_image_at(
        &self,
        r_wc: &Mat3,
        center: Vec3,
        settings: &RenderSettings,
        tau: f64,
    ) -> Vec<f32> {
        let mut linear = vec![0.0f32; 3 * self.width * self.height];
        self.rows_at(r_wc, center, settings, tau, Rows::Linear(&mut linear));
        linear
    }

    /// Renders every row into `out`: the sensor's 8-bit output, or the linear values.
    fn rows(&self, r_wc: &Mat3, center: Vec3, settings: &RenderSettings, out: Rows<'_>) {
        self.rows_at(r_wc, center, settings, 0.0, out)
    }

    /// The camera's pose `tau` seconds after the frame's time, moving as `settings` says.
    fn pose_at(&self, rw: &[[f64; 3]; 3], c: [f64; 3], settings: &RenderSettings, tau: f64) -> View {
        let dr = rotation_exp(settings.rates_rad_s, tau);
        let mut r = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                r[i][j] = (0..3).map(|k| dr[i][k] * rw[k][j]).sum();
            }
        }
        self.view(&r, [0, 1, 2].map(|k| c[k] + settings.velocity_m_s[k] * tau))
    }

    fn view(&self, rw: &[[f64; 3]; 3], c: [f64; 3]) -> View {
        let polys = self
            .painted
            .iter()
            .filter_map(|(pts, albedo)| {
                let p = self.wall_polygon(pts, rw, c)?;
                let (_, y0, _, y1) = p.bounds();
                Some((p, *albedo, (y0 + 0.5).floor() as i64, (y1 - 0.5).ceil() as i64))
            })
            .collect();
        let col = |k: usize| [rw[0][k], rw[1][k], rw[2][k]];
        let (ex, ey, ez) = (col(0), col(1), col(2));
        let du = [ex[0] / self.fx, ex[1] / self.fx, ex[2] / self.fx].map(|v| v as f32);
        View { ex, ey, ez, du, cf: c.map(|v| v as f32), polys }
    }

    /// [`Self::rows`] at `tau0` seconds after the frame's time (a sub-frame of a motion-blurred exposure).
    fn rows_at(&self, r_wc: &Mat3, center: Vec3, settings: &RenderSettings, tau0: f64, out: Rows<'_>) {
        let rw = to64(r_wc);
        let c = [center.x as f64, center.y as f64, center.z as f64];
        let frame = self.pose_at(&rw, c, settings, tau0);
        let moving = settings.velocity_m_s.iter().chain(&settings.rates_rad_s).any(|v| *v != 0.0);
        let rolling = self.line_delay_s > 0.0 && moving;
        let mid_row = (self.height as f64 - 1.0) / 2.0;
        let (w, h) = (self.width, self.height);
        let scale = 255.0 * self.exposure * settings.exposure_gain as f32 * self.auto_exposure(settings.seed);
        let vignette = match (&out, &self.vignette) {
            (Rows::Encoded(_), Some(v)) => Some(v.as_slice()),
            _ => None,
        };
        let (g0, [gx, gz]) = (settings.light_gain as f32, settings.light_gradient_per_m.map(|v| v as f32));
        let (lcx, lcz) = (self.line_center[0] as f32, self.line_center[2] as f32);
        let noise = self.noise_block(settings.seed);
        let sigma = settings.noise_sigma as f32 / NOISE_SCALE;
        let st = &self.stack;
        // One row of the image into `px_row` (3 w bytes) or, with blur, `lin_row` (3 w linear values): every
        // row depends on the scene, the pose and its own slice of the noise only, so bands of rows render on
        // separate threads with the same result as one thread.
        let render_row = |v: usize,
                          sc: &mut RowScratch,
                          px_row: Option<&mut [u8]>,
                          lin_row: Option<&mut [f32]>| {
            let RowScratch {
                mut cov,
                mut gain,
                mut idx,
                mut planes,
                mut qplanes,
                mut on_wall,
                mut xs,
                mut bs,
                mut tex,
                mut lit,
                mut cov_sum,
                mut paint,
            } = std::mem::replace(sc, RowScratch::empty());
            // With a rolling shutter this row sees the scene from where the camera is when it is exposed
            // (rows are timed from the middle one).
            let local;
            let vw = if rolling {
                local = self.pose_at(&rw, c, settings, tau0 + (v as f64 - mid_row) * self.line_delay_s);
                &local
            } else {
                &frame
            };
            let View { ex, ey, ez, du, cf, ref polys } = *vw;
            let yn = (v as f64 - self.cy) / self.fy;
            let xn0 = -self.cx / self.fx;
            let d0 = [0, 1, 2].map(|k| (ex[k] * xn0 + ey[k] * yn + ez[k]) as f32);
            // Paint coverage of this row (exact box-filter areas; shapes are assumed not to overlap). Most rows
            // have none: they take the plain shading path below.
            let mut painted_row = false;
            for (p, albedo, y0, y1) in polys {
                if (v as i64) < *y0 || (v as i64) > *y1 {
                    continue;
                }
                if !painted_row {
                    cov_sum.fill(0.0);
                    for p in paint.iter_mut() {
                        p.fill(0.0);
                    }
                }
                if row_coverage(p, v as i64, &mut cov).is_none() {
                    continue;
                }
                painted_row = true;
                for (ch, plane) in paint.iter_mut().enumerate() {
                    for (q, &k) in plane.iter_mut().zip(&cov) {
                        *q += k * albedo[ch];
                    }
                }
                for (s, &k) in cov_sum.iter_mut().zip(&cov) {
                    *s += k;
                }
            }
            // Pass 1: ray hit, texture index, illumination. The surface coordinates are exact every SPAN
            // pixels and linear in between when both ends hit the same plane (the perspective error over a
            // span is far below a texel; the painted shapes' coverage above is exact regardless).
            let hit = |u: usize| -> (f32, f32, f32) {
                let uf = u as i32 as f32;
                let (dx, dy, dz) = (d0[0] + uf * du[0], d0[1] + uf * du[1], d0[2] + uf * du[2]);
                // Nearest of the wall (y = 0) and the floor (z = 0) without dividing twice:
                // t_wall <= t_floor  <=>  c_y |d_z| <= c_z |d_y| when both are hit.
                let hits_wall = dy < 0.0;
                let hits_floor = dz < 0.0;
                let wall = hits_wall && (!hits_floor || cf[1] * -dz <= cf[2] * -dy);
                let (num, den) = if wall { (cf[1], dy) } else { (cf[2], dz) };
                // Neither plane hit (looking up and away): a far distance; the texture index is clamped.
                let t = if hits_wall || hits_floor { -num / den } else { 1e6 };
                let x = cf[0] + t * dx;
                let b = if wall { cf[2] + t * dz } else { cf[1] + t * dy };
                (x, b, if wall { 1.0 } else { 0.0 })
            };
            let mut u0 = 0usize;
            let mut a = hit(0);
            while u0 < w {
                let u1 = (u0 + SPAN).min(w - 1);
                let bnd = hit(u1);
                let end = if u1 == w - 1 { w } else { u1 };
                if a.2 == bnd.2 {
                    let inv = 1.0 / (u1 - u0).max(1) as f32;
                    let (sx, sb) = ((bnd.0 - a.0) * inv, (bnd.1 - a.1) * inv);
                    for (k, ((x, b), wf)) in
                        xs[u0..end].iter_mut().zip(&mut bs[u0..end]).zip(&mut on_wall[u0..end]).enumerate()
                    {
                        let kf = k as i32 as f32;
                        *x = a.0 + kf * sx;
                        *b = a.1 + kf * sb;
                        *wf = a.2;
                    }
                } else {
                    for u in u0..end {
                        (xs[u], bs[u], on_wall[u]) = hit(u);
                    }
                }
                u0 = end;
                a = bnd;
            }
            for ((((i, g), &x), &b), &wf) in
                idx.iter_mut().zip(gain.iter_mut()).zip(&xs).zip(&bs).zip(&on_wall)
            {
                let b_max = st.floor_max + wf * (st.wall_max - st.floor_max);
                let row0 = st.wall_rows_f * (1.0 - wf);
                // Clamp in the float domain (max() maps NaN to the bound), then convert branch-free.
                let fx = ((x - st.origin_x) * st.inv_texel).max(0.0).min(st.x_max);
                let fb = (b * st.inv_texel).max(0.0).min(b_max);
                // The index is formed in f32 (exact: the stacked table has fewer than 2^22 texels).
                *i = floor_small((floor_f(fb) + row0) * st.width_f + fx);
                *g = (g0 * (1.0 + gx * (x - lcx) + gz * (wf * b - lcz))).max(0.0) * scale;
            }
            // Pass 2: texture fetch, and its product with the illumination (shared by the three channels of
            // the unpainted rows).
            for (t, &i) in tex.iter_mut().zip(&idx) {
                *t = st.data.get(i as usize).copied().unwrap_or(64) as f32 * (1.0 / 64.0);
            }
            if !painted_row {
                for (gm, (&g, &m)) in lit.iter_mut().zip(gain.iter().zip(&tex)) {
                    *gm = g * m;
                }
            }
            // Pass 3: shading, per channel (planar, vectorisable); for the sensor's output, its response
            // (clipping, tone curve, noise, quantisation) on the row.
            for (ch, plane) in planes.iter_mut().enumerate() {
                let (wall_a, floor_a) = (self.wall_albedo[ch], self.floor_albedo[ch]);
                if painted_row {
                    for (((((p, &k), &pt), &wl), &g), &m) in
                        plane.iter_mut().zip(&cov_sum).zip(&paint[ch]).zip(&on_wall).zip(&gain).zip(&tex)
                    {
                        let base = floor_a + wl * (wall_a - floor_a);
                        *p = g * (pt + (1.0 - k.min(1.0)) * base * m);
                    }
                } else {
                    for ((p, &wl), &gm) in plane.iter_mut().zip(&on_wall).zip(&lit) {
                        *p = (floor_a + wl * (wall_a - floor_a)) * gm;
                    }
                }
                if px_row.is_some() {
                    if let Some(vg) = vignette {
                        for (p, g) in plane.iter_mut().zip(&vg[v * w..(v + 1) * w]) {
                            *p *= g;
                        }
                    }
                    let nz = &noise[(ch * h + v) * w..(ch * h + v + 1) * w];
                    self.response.finish(plane, nz, sigma, &mut qplanes[ch]);
                }
            }
            // Pass 4: interleave.
            if let Some(out) = lin_row {
                for (((o, r), g), b) in
                    out.chunks_exact_mut(3).zip(&planes[0]).zip(&planes[1]).zip(&planes[2])
                {
                    o.copy_from_slice(&[*r, *g, *b]);
                }
            }
            if let Some(px_row) = px_row {
                for (((px, r), g), b) in
                    px_row.chunks_exact_mut(3).zip(&qplanes[0]).zip(&qplanes[1]).zip(&qplanes[2])
                {
                    px.copy_from_slice(&[*r, *g, *b]);
                }
            }
            *sc = RowScratch { cov, gain, idx, planes, qplanes, on_wall, xs, bs, tex, lit, cov_sum, paint };
        };
        // Bands of rows on the thread pool (a flight's frames are rendered one after another, so the pool's
        // threads are otherwise idle; in a sweep the runs already fill them and the bands run inline).
        let band = ROW_BAND.min(h.max(1));
        match out {
            Rows::Linear(linear) => linear.par_chunks_mut(3 * w * band).enumerate().for_each_init(
                || RowScratch::new(w),
                |sc, (b, rows)| {
                    for (k, row) in rows.chunks_exact_mut(3 * w).enumerate() {
                        render_row(b * band + k, sc, None, Some(row));
                    }
                },
            ),
            Rows::Encoded(data) => data.par_chunks_mut(3 * w * band).enumerate().for_each_init(
                || RowScratch::new(w),
                |sc, (b, rows)| {
                    for (k, row) in rows.chunks_exact_mut(3 * w).enumerate() {
                        render_row(b * band + k, sc, Some(row), None);
                    }
                },
            ),
        }
    }

    /// This frame's block of standard-normal noise (scaled by `NOISE_SCALE`): a window of the renderer's
    /// noise buffer at an offset drawn from the frame's seed.
    fn noise_block(&self, seed: u64) -> &[i8] {
        let need = 3 * self.width * self.height;
        let mut s = seed ^ 0xA5A5_5A5A_DEAD_BEEF;
        let off = (splitmix64(&mut s) % (self.noise.len() - need) as u64) as usize;
        &self.noise[off..off + need]
    }

    /// The image of a convex polygon painted on the wall (vertices `(x, z)`), in pixel coordinates, clipped
    /// to the near plane.
    fn wall_polygon(&self, pts: &[[f64; 2]], rw: &[[f64; 3]; 3], c: [f64; 3]) -> Option<Poly> {
        // Camera coordinates: R_CW (P - C) = R_WC^T (P - C).
        let cam: Vec<[f64; 3]> = pts
            .iter()
            .map(|p| {
                let d = [p[0] - c[0], -c[1], p[1] - c[2]];
                [0, 1, 2].map(|k| rw[0][k] * d[0] + rw[1][k] * d[1] + rw[2][k] * d[2])
            })
            .collect();
        const NEAR: f64 = 0.01;
        let mut clipped: Vec<[f64; 3]> = Vec::with_capacity(cam.len() + 2);
        for k in 0..cam.len() {
            let (p, q) = (cam[k], cam[(k + 1) % cam.len()]);
            if p[2] >= NEAR {
                clipped.push(p);
            }
            if (p[2] >= NEAR) != (q[2] >= NEAR) {
                let t = (NEAR - p[2]) / (q[2] - p[2]);
                clipped.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]), NEAR]);
            }
        }
        if clipped.len() < 3 {
            return None;
        }
        let px: Vec<[f64; 2]> = clipped
            .iter()
            .map(|p| [self.fx * p[0] / p[2] + self.cx, self.fy * p[1] / p[2] + self.cy])
            .collect();
        Some(Poly::new(&px))
    }
}

/// Where [`ForwardRenderer::rows`] writes: the sensor's output or the linear values (both interleaved RGB).
enum Rows<'a> {
    Encoded(&'a mut [u8]),
    Linear(&'a mut [f32]),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn branch_free_conversions_are_exact() {
        for &v in &[0.0f32, 0.2, 0.5, 0.7, 1.5, 2.49, 2.5, 4095.99, 1_000_000.3, 4_194_302.7] {
            assert_eq!(floor_small(v), v.floor() as i32, "{v}");
            assert_eq!(floor_f(v), v.floor(), "{v}");
        }
        // At integers the tie goes to even: the texel below or the texel itself.
        for &v in &[1.0f32, 2.0, 255.0, 4_194_303.0] {
            let d = v.floor() as i32 - floor_small(v);
            assert!(d == 0 || d == 1, "{v}");
            assert_eq!(floor_f(v), floor_small(v) as f32);
        }
        for &(v, q) in &[
            (-3.0f32, 0u8),
            (0.4, 0),
            (0.6, 1),
            (1.5, 2),
            (2.5, 2),
            (254.6, 255),
            (300.0, 255),
            (f32::NAN, 0),
        ] {
            assert_eq!(quantise(v), q, "{v}");
        }
    }

    /// The paper scene, level, facing the line's middle from 1.3 m, without noise.
    fn clean_view(s: &crate::Scenario, seed: u64) -> RgbImage {
        let r = ForwardRenderer::new(s).unwrap();
        let mount = s.forward_camera_mount();
        let r_wc = geometry::frames::Attitude::default().world_from_body().mul_mat(&mount.body_from_camera);
        let mut st = r.default_settings();
        (st.seed, st.noise_sigma) = (seed, 0.0);
        r.render(&r_wc, Vec3::new(1.15, 1.3, 1.0), &st)
    }

    fn grey_at(img: &RgbImage, u: usize, v: usize) -> u8 {
        img.data[3 * (v * img.width + u) + 1]
    }

    #[test]
    fn vignetting_darkens_the_corners_only() {
        let mut s = crate::Scenario::paper();
        let plain = clean_view(&s, 1);
        s.forward_camera.vignetting = 0.5;
        let vignetted = clean_view(&s, 1);
        // The centre keeps its light; a corner gets half of it: sRGB of half the light is 0.73 of the value
        // (the wall's green at 1.0 is 0.68 linear, 216; half of it 0.34 linear, 158).
        assert_eq!(grey_at(&plain, 320, 240), grey_at(&vignetted, 320, 240));
        let (a, b) = (grey_at(&plain, 0, 0) as f32, grey_at(&vignetted, 0, 0) as f32);
        assert!((b / a - 0.73).abs() < 0.03, "corner {a} -> {b}");
        let (a, b) = (grey_at(&plain, 320, 0) as f32, grey_at(&vignetted, 320, 0) as f32);
        assert!(b < a && b > 0.8 * a, "top middle {a} -> {b}");
    }

    #[test]
    fn auto_exposure_changes_between_frames_by_the_seed() {
        let mut s = crate::Scenario::paper();
        assert_eq!(grey_at(&clean_view(&s, 1), 320, 20), grey_at(&clean_view(&s, 2), 320, 20));
        s.forward_camera.exposure_step = 0.3;
        let levels: Vec<u8> = (0..20).map(|k| grey_at(&clean_view(&s, k), 320, 20)).collect();
        let (lo, hi) = (*levels.iter().min().unwrap(), *levels.iter().max().unwrap());
        // The wall's green (0.68 linear at exposure 1, 216) within exposures 0.7-1.3: 183-243.
        assert!(lo >= 180 && hi <= 246 && hi - lo > 30, "{levels:?}");
        assert_eq!(clean_view(&s, 7), clean_view(&s, 7));
    }

    #[test]
    fn jpeg_delivers_a_compressed_frame() {
        let mut s = crate::Scenario::paper();
        let plain = clean_view(&s, 1);
        s.forward_camera.jpeg_quality = 60;
        let jpeg = clean_view(&s, 1);
        assert_eq!(jpeg, clean_view(&s, 1));
        let diff: Vec<i32> = plain.data.iter().zip(&jpeg.data).map(|(a, b)| *a as i32 - *b as i32).collect();
        let mean_abs = diff.iter().map(|d| d.abs() as f64).sum::<f64>() / diff.len() as f64;
        // Changed, but by a few grey levels on average (the band's edges and the texture).
        assert!(mean_abs > 0.2 && mean_abs < 4.0, "{mean_abs}");
    }

    /// The column of a vertical blue bar's centre in row `v` (blue minus red weighted, noise-free frames).
    fn bar_column(img: &RgbImage, v: usize) -> f64 {
        let (mut s, mut su) = (0.0, 0.0);
        for u in 0..img.width {
            let p = &img.data[3 * (v * img.width + u)..3 * (v * img.width + u) + 3];
            let b = (p[2] as f64 - p[0] as f64).max(0.0);
            s += b;
            su += b * u as f64;
        }
        su / s
    }

    #[test]
    fn a_rolling_shutter_slants_what_moves_and_motion_blurs() {
        // A blue bar from the floor to 2 m on the wall, the camera moving along x at 1 m/s, 1.3 m from the
        // wall: the image moves by f v / d = 246 px/s. With 30 us per row, rows 40 and 440 are exposed 12 ms
        // apart: the bar is 2.95 px further along in one than in the other. Without the rolling shutter, or
        // without motion, the bar is straight.
        let mut s = crate::Scenario::paper();
        s.scene.shapes.push(crate::scenario::WallShape::Polygon {
            points_m: vec![[1.10, 0.0], [1.20, 0.0], [1.20, 2.0], [1.10, 2.0]],
            albedo_rgb: [0.1, 0.1, 0.8],
        });
        s.forward_camera.response = vision_core::ToneCurve::Linear;
        let mount = s.forward_camera_mount();
        let r_wc = geometry::frames::Attitude::default().world_from_body().mul_mat(&mount.body_from_camera);
        let centre = Vec3::new(1.15, 1.3, 1.0);
        let frame = |s: &crate::Scenario, velocity: [f64; 3]| {
            let r = ForwardRenderer::new(s).unwrap();
            let mut st = r.default_settings();
            (st.noise_sigma, st.velocity_m_s) = (0.0, velocity);
            r.render(&r_wc, centre, &st)
        };
        let slant = |img: &RgbImage| bar_column(img, 440) - bar_column(img, 40);
        let still = frame(&s, [0.0; 3]);
        assert!(slant(&still).abs() < 0.01, "{}", slant(&still));
        assert_eq!(frame(&s, [1.0, 0.0, 0.0]), still, "a global shutter without exposure time");
        s.forward_camera.line_delay_s = 30e-6;
        assert_eq!(frame(&s, [0.0; 3]), still, "no motion");
        let moving = frame(&s, [1.0, 0.0, 0.0]);
        let expected = 320.0 * 1.0 / 1.3 * 400.0 * 30e-6;
        // Facing the wall (-y), the image's right is the world's -x: moving +x, the scene moves right in the
        // image, the later rows further.
        assert!((slant(&moving) - expected).abs() < 0.05 * expected, "{} vs {expected}", slant(&moving));
        // Rows are timed from the middle one: row 100 is exposed 4.2 ms before the frame's time, row 380 as
        // much after.
        for v in [100usize, 380] {
            let want = 320.0 / 1.3 * (v as f64 - 239.5) * 30e-6;
            let got = bar_column(&moving, v) - bar_column(&still, v);
            assert!((got - want).abs() < 0.05, "row {v}: {got} px, expected {want}");
        }
        // Motion blur: a 10 ms exposure at 1 m/s smears the bar by 2.5 px; its centre stays, its edges soften.
        s.forward_camera.line_delay_s = 0.0;
        s.forward_camera.exposure_time_s = 0.01;
        let blurred = frame(&s, [1.0, 0.0, 0.0]);
        assert!((bar_column(&blurred, 100) - bar_column(&still, 100)).abs() < 0.05);
        // Partly covered pixels of row 100: blue minus red between the wall's (below 0) and the bar's (178).
        let edge = |img: &RgbImage| {
            (0..img.width)
                .filter(|&u| {
                    let p = &img.data[3 * (100 * img.width + u)..3 * (100 * img.width + u) + 3];
                    (10..168).contains(&(p[2] as i32 - p[0] as i32))
                })
                .count()
        };
        // Measured: 4 partly covered pixels against 2.
        assert!(
            edge(&blurred) >= 2 * edge(&still) && edge(&still) > 0,
            "{} vs {}",
            edge(&blurred),
            edge(&still)
        );
    }

    #[test]
    fn renders_are_deterministic_and_the_line_is_red() {
        let s = crate::Scenario::paper();
        let r = ForwardRenderer::new(&s).unwrap();
        let mount = s.forward_camera_mount();
        let r_wc = geometry::frames::Attitude::default().world_from_body().mul_mat(&mount.body_from_camera);
        let mut st = r.default_settings();
        st.seed = 3;
        let a = r.render(&r_wc, Vec3::new(1.15, 1.3, 1.0), &st);
        let b = r.render(&r_wc, Vec3::new(1.15, 1.3, 1.0), &st);
        assert_eq!(a, b);
        // Level at the line's height, facing its middle: the image centre is red, the top is wall.
        let c = &a.data[3 * (240 * 640 + 320)..3 * (240 * 640 + 320) + 3];
        // The sRGB camera lifts the paint's dark green and blue (linear 0.12 and 0.10) to about 100.
        assert!(c[0] > 200 && c[1] < 115 && c[2] < 115 && c[0] > 2 * c[1], "{c:?}");
        let t = &a.data[3 * (20 * 640 + 320)..3 * (20 * 640 + 320) + 3];
        assert!(t[0] > 140 && t[1] > 140, "{t:?}");
        st.seed = 4;
        assert_ne!(a, r.render(&r_wc, Vec3::new(1.15, 1.3, 1.0), &st));
    }
}
