//! Optical flow of the downward camera and the velocity it gives (paper eq. 35-36, done in full).
//!
//! 1. **Pyramids** of both frames (2x2 averaging, up to [`MAX_LEVELS`] levels), kept in a caller-owned
//!    workspace: the next frame's pyramid is reused as the previous one of the following pair.
//! 2. **Features**: Shi-Tomasi minimum-eigenvalue score on pyramid level 1, the best corner of each cell of a
//!    grid, so that features spread over the image; cells without texture give none.
//! 3. **Tracking**: pyramidal Lucas-Kanade (Bouguet 2000) with bilinear sub-pixel sampling, an iteration and
//!    a convergence limit, started from a prediction of the rotational flow (from the gyro), then a
//!    forward-backward check. A track that leaves the image or does not converge is dropped, never wrapped.
//! 4. **Aggregation** ([`FlowStats`]): a robust fit of an affine flow field (MAD rejection), then the inliers'
//!    mean displacement and the moments of their positions. A per-axis median of raw displacements would be
//!    biased where the rotational flow varies across the image; the trimmed affine fit is robust without that
//!    bias. The statistics are a few numbers that can cross the radio link.
//! 5. **Velocity** ([`FlowStats::velocity`]): the rotational flow of the rotation integrated over exactly the
//!    frame interval is removed, for the inliers' actual positions, with the full pinhole flow model
//!    (`x' = x + x y t_x - (1 + x^2) t_y + y t_z` for rotation, `x' = x - T_x / Z + x T_z / Z` for translation,
//!    similarly for `y`), and the remaining translational flow is scaled by the depth of the floor, `1 / Z`
//!    being linear across the image for a plane. Eq. 35-36 is the one-dimensional special case at the image
//!    centre of a level camera.
use crate::camera::CameraModel;
use crate::image::Gray8View;
use geometry::{Vec2, Vec3};

/// Pyramid levels at most.
pub const MAX_LEVELS: usize = 3;
/// Largest frame the flow workspace holds.
pub const FLOW_MAX_W: usize = 320;
/// Largest frame height the flow workspace holds.
pub const FLOW_MAX_H: usize = 240;
/// Features tracked at most.
pub const MAX_FEATURES: usize = 64;
const MAX_WIN: usize = 13; // window side at most (half window 6)

/// Why a frame pair gave no flow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NoFlowReason {
    /// The frames differ in size, or exceed the workspace.
    BadImageSize,
    /// No texture: no corner passed the minimum-eigenvalue threshold.
    NoTexture,
    /// Too few tracks survived (lost, not converged, failed the forward-backward check, or outliers).
    TooFewTracks,
    /// The tracks do not agree on one flow field: too few of the selected features are inliers, or the inliers
    /// scatter too much about the fit (typically motion beyond the pyramid's reach on a repetitive floor).
    Inconsistent,
}

impl NoFlowReason {
    /// Short explanation.
    pub fn describe(&self) -> &'static str {
        match self {
            NoFlowReason::BadImageSize => "the frames differ in size or exceed 320x240",
            NoFlowReason::NoTexture => "the floor shows no texture to track",
            NoFlowReason::TooFewTracks => {
                "too few features could be tracked (motion beyond reach, blur, or occlusion)"
            }
            NoFlowReason::Inconsistent => {
                "the tracks disagree on the flow (motion beyond reach on a repetitive floor?)"
            }
        }
    }

    /// Stable identifier.
    pub fn code(&self) -> &'static str {
        match self {
            NoFlowReason::BadImageSize => "bad_image_size",
            NoFlowReason::NoTexture => "no_texture",
            NoFlowReason::TooFewTracks => "too_few_tracks",
            NoFlowReason::Inconsistent => "inconsistent",
        }
    }
}

/// Tuning of the flow.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FlowParams {
    /// Pyramid levels (1 to 3).
    pub levels: u8,
    /// Half side of the tracking window (window `2h + 1` pixels, h up to 6).
    pub window_half: u8,
    /// Iteration limit per level.
    pub max_iterations: u8,
    /// Convergence: stop when the update is below this (px).
    pub epsilon_px: f32,
    /// Grid of cells for spreading the features (columns, rows); one feature per cell at most.
    pub grid: [u8; 2],
    /// Minimum eigenvalue of the structure tensor per window pixel, in grey levels squared per pixel squared.
    pub min_eigen: f32,
    /// Largest forward-backward disagreement (px).
    pub fb_max_px: f32,
    /// Fewest surviving tracks for a flow.
    pub min_tracks: u8,
    /// Outliers: residuals beyond this many robust standard deviations of the affine fit.
    pub outlier_sigmas: f32,
    /// Smallest quality (inliers over selected features) for a flow.
    pub min_quality: f32,
    /// Largest RMS residual of the inliers about the affine fit (px).
    pub max_residual_px: f32,
}

impl Default for FlowParams {
    fn default() -> Self {
        Self {
            levels: 3,
            window_half: 4,
            max_iterations: 12,
            epsilon_px: 0.01,
            grid: [8, 6],
            min_eigen: 25.0,
            fb_max_px: 0.3,
            min_tracks: 8,
            outlier_sigmas: 3.0,
            min_quality: 0.35,
            max_residual_px: 0.5,
        }
    }
}

/// The flow of one frame pair, compact enough for the radio link. Positions and displacements are in
/// normalised (undistorted) image coordinates of the camera; the moments are over the inlier tracks.
///
/// The flow is robust by construction: each track's displacement less the rotational flow of
/// `predicted_rotation` at its own position, then the per-axis **median** over the inliers of an affine fit.
/// Whoever knows the rotation better (the flight controller, from its attitude history over exactly the frame
/// interval) corrects for the difference with [`FlowStats::rotational_flow`], which is linear in the rotation.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FlowStats {
    /// Median over the inliers of the displacement less the rotational flow of `predicted_rotation`.
    pub flow: Vec2,
    /// The camera rotation (camera frame, rad) whose flow was removed from `flow`.
    pub predicted_rotation: Vec3,
    /// Mean position of the inliers.
    pub mean_pos: Vec2,
    /// Means of x^2, y^2 and x y over the inliers.
    pub mean_sq: [f32; 3],
    /// Inlier tracks.
    pub inliers: u16,
    /// Features selected.
    pub selected: u16,
    /// RMS residual of the inliers about the affine fit (normalised units).
    pub residual_rms: f32,
    /// Median raw displacement of the inliers (pixels), for reports.
    pub median_flow_px: Vec2,
    /// Quality, 0 (unusable) to 1: the fraction of selected features that became inliers.
    pub quality: f32,
}

/// A velocity from the flow.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FlowVelocity {
    /// Camera velocity along the camera's x and y axes (m/s).
    pub velocity_cam_m_s: Vec2,
    /// Standard deviation per axis (m/s).
    pub std_m_s: f32,
}

/// Rotational displacement (normalised) at `(x, y)` for a small camera rotation `r` (rad): the pinhole flow
/// model's rotational part, exact to first order in the rotation.
#[inline]
fn rot_flow_at(x: f32, y: f32, r: Vec3) -> Vec2 {
    Vec2::new(x * y * r.x - (1.0 + x * x) * r.y + y * r.z, (1.0 + y * y) * r.x - x * y * r.y - x * r.z)
}

impl FlowStats {
    /// Mean rotational displacement over the inliers for a small camera rotation `rot` (camera frame, rad).
    pub fn rotational_flow(&self, rot: Vec3) -> Vec2 {
        let (x, y) = (self.mean_pos.x, self.mean_pos.y);
        let [xx, yy, xy] = self.mean_sq;
        Vec2::new(xy * rot.x - (1.0 + xx) * rot.y + y * rot.z, (1.0 + yy) * rot.x - xy * rot.y - x * rot.z)
    }

    /// The translational flow (normalised) given the camera's rotation over exactly the frame interval.
    pub fn translational_flow(&self, rot: Vec3) -> Vec2 {
        self.flow - self.rotational_flow(rot - self.predicted_rotation)
    }

    /// The camera's velocity over the interval `dt` (s), given its rotation over exactly that interval
    /// (`rot`, camera frame, rad), the floor's unit normal in camera coordinates pointing away from the camera
    /// (`floor_normal_cam`, `(0, 0, 1)` when looking straight down), the distance to the floor along the optical
    /// axis (`range_m`), the camera's velocity along its optical axis (`vz_cam_m_s`, 0 if unknown) and the
    /// tracking noise floor (`pixel_sigma`, normalised units). `None` when the geometry is degenerate.
    pub fn velocity(
        &self,
        rot: Vec3,
        dt: f32,
        range_m: f32,
        floor_normal_cam: Vec3,
        vz_cam_m_s: f32,
        pixel_sigma: f32,
    ) -> Option<FlowVelocity> {
        let n = floor_normal_cam;
        if !(dt > 0.0 && range_m > 0.0 && n.z > 0.1) || self.inliers == 0 {
            return None;
        }
        // 1/Z is linear in (x, y) for a plane; the flow is taken at the inliers' mean position.
        let inv_z = (n.x * self.mean_pos.x + n.y * self.mean_pos.y + n.z) / (range_m * n.z);
        if !(inv_z > 0.0) {
            return None;
        }
        let trans = self.translational_flow(rot);
        let tz = vz_cam_m_s * dt;
        // trans = -T_xy / Z + pos T_z / Z  =>  T_xy = pos T_z - trans Z.
        let z = 1.0 / inv_z;
        let t = self.mean_pos * tz - trans * z;
        let v = t * (1.0 / dt);
        // Noise of the median: per-track residual (or the noise floor) times 1.25 over sqrt(inliers).
        let per_track = self.residual_rms.max(pixel_sigma);
        let std = 1.25 * per_track * z / dt / libm::sqrtf(self.inliers as f32);
        Some(FlowVelocity { velocity_cam_m_s: v, std_m_s: std })
    }
}

#[derive(Clone, Copy)]
struct Level {
    w: usize,
    h: usize,
    off: usize,
}

/// One image pyramid in a fixed buffer.
struct Pyramid {
    data: [u8; FLOW_MAX_W * FLOW_MAX_H * 4 / 3 + 64],
    levels: [Level; MAX_LEVELS],
    n: usize,
}

impl Pyramid {
    const fn new() -> Self {
        Self {
            data: [0; FLOW_MAX_W * FLOW_MAX_H * 4 / 3 + 64],
            levels: [Level { w: 0, h: 0, off: 0 }; MAX_LEVELS],
            n: 0,
        }
    }

    fn build(&mut self, img: &Gray8View<'_>, levels: usize) {
        let (w, h) = (img.width(), img.height());
        self.levels[0] = Level { w, h, off: 0 };
        for y in 0..h {
            self.data[y * w..(y + 1) * w].copy_from_slice(img.row(y));
        }
        let mut off = w * h;
        self.n = 1;
        for l in 1..levels {
            let p = self.levels[l - 1];
            let (lw, lh) = (p.w / 2, p.h / 2);
            if lw < 8 || lh < 8 {
                break;
            }
            for y in 0..lh {
                for x in 0..lw {
                    let i = p.off + 2 * y * p.w + 2 * x;
                    let s = self.data[i] as u16
                        + self.data[i + 1] as u16
                        + self.data[i + p.w] as u16
                        + self.data[i + p.w + 1] as u16;
                    self.data[off + y * lw + x] = ((s + 2) / 4) as u8;
                }
            }
            self.levels[l] = Level { w: lw, h: lh, off };
            off += lw * lh;
            self.n += 1;
        }
    }

    #[inline]
    fn px(&self, l: &Level, x: usize, y: usize) -> f32 {
        self.data[l.off + y * l.w + x] as f32
    }

    /// Bilinear sample; `None` outside the image, or, with `clamp`, the nearest border sample (used on the
    /// coarse levels, where a window near the border would otherwise lose the track before level 0 decides).
    #[inline]
    fn sample(&self, l: &Level, x: f32, y: f32, clamp: bool) -> Option<f32> {
        let (xm, ym) = ((l.w - 1) as f32, (l.h - 1) as f32);
        let (x, y) = if clamp && x.is_finite() && y.is_finite() {
            (x.clamp(0.0, xm - 1e-3), y.clamp(0.0, ym - 1e-3))
        } else {
            (x, y)
        };
        if !(x >= 0.0 && y >= 0.0 && x < xm && y < ym) {
            return None;
        }
        let (xi, yi) = (x as usize, y as usize);
        let (fx, fy) = (x - xi as f32, y - yi as f32);
        let i = l.off + yi * l.w + xi;
        let d = &self.data;
        let a = d[i] as f32 + fx * (d[i + 1] as f32 - d[i] as f32);
        let b = d[i + l.w] as f32 + fx * (d[i + l.w + 1] as f32 - d[i + l.w] as f32);
        Some(a + fy * (b - a))
    }
}

/// Buffers of the flow (about 200 KB: two pyramids of up to 320x240). One per downward camera.
pub struct FlowWorkspace {
    pyr: [Pyramid; 2],
    prev: usize,
    has_prev: bool,
    feats: [Vec2; MAX_FEATURES],
    tracks: [(Vec2, Vec2); MAX_FEATURES],
    inlier: [bool; MAX_FEATURES],
    scratch: [f32; MAX_FEATURES],
}

impl Default for FlowWorkspace {
    fn default() -> Self {
        Self::new()
    }
}

impl FlowWorkspace {
    /// Empty buffers.
    pub const fn new() -> Self {
        Self {
            pyr: [Pyramid::new(), Pyramid::new()],
            prev: 0,
            has_prev: false,
            feats: [Vec2::ZERO; MAX_FEATURES],
            tracks: [(Vec2::ZERO, Vec2::ZERO); MAX_FEATURES],
            inlier: [false; MAX_FEATURES],
            scratch: [0.0; MAX_FEATURES],
        }
    }

    /// Forgets the previous frame.
    pub fn reset(&mut self) {
        self.has_prev = false;
    }
}

/// Selects up to one feature per grid cell on pyramid level 1 (or 0 for one-level pyramids): the pixel with
/// the largest minimum eigenvalue of its 3x3 structure tensor, above `min_eigen`. Returns level-0 positions.
fn select_features(p: &Pyramid, params: &FlowParams, out: &mut [Vec2; MAX_FEATURES]) -> usize {
    let li = if p.n > 1 { 1 } else { 0 };
    let l = p.levels[li];
    let scale = (1 << li) as f32;
    let (gx, gy) = (params.grid[0].max(1) as usize, params.grid[1].max(1) as usize);
    let margin = 2 + (params.window_half as usize + 1) / (1 << li);
    let mut n = 0;
    for cy in 0..gy {
        for cx in 0..gx {
            let (x0, x1) = ((cx * l.w / gx).max(margin), ((cx + 1) * l.w / gx).min(l.w - margin));
            let (y0, y1) = ((cy * l.h / gy).max(margin), ((cy + 1) * l.h / gy).min(l.h - margin));
            let mut best = (params.min_eigen * 9.0, None);
            for y in y0..y1 {
                for x in x0..x1 {
                    let (mut sxx, mut syy, mut sxy) = (0.0f32, 0.0f32, 0.0f32);
                    for dy in 0..3 {
                        for dx in 0..3 {
                            let (u, v) = (x + dx - 1, y + dy - 1);
                            let ix = 0.5 * (p.px(&l, u + 1, v) - p.px(&l, u - 1, v));
                            let iy = 0.5 * (p.px(&l, u, v + 1) - p.px(&l, u, v - 1));
                            sxx += ix * ix;
                            syy += iy * iy;
                            sxy += ix * iy;
                        }
                    }
                    let (lmin, _, _) = geometry::solve::sym2_eigen(sxx, sxy, syy);
                    if lmin > best.0 {
                        best = (lmin, Some((x, y)));
                    }
                }
            }
            if let (Some((x, y)), true) = (best.1, n < MAX_FEATURES) {
                out[n] =
                    Vec2::new(x as f32 * scale + 0.5 * (scale - 1.0), y as f32 * scale + 0.5 * (scale - 1.0));
                n += 1;
            }
        }
    }
    n
}

/// Lucas-Kanade at one level: refines the displacement `d` of the window centred at `p` from `a` to `b`.
fn lk_level(a: &Pyramid, b: &Pyramid, l: usize, p: Vec2, mut d: Vec2, params: &FlowParams) -> Option<Vec2> {
    let (la, lb) = (a.levels[l], b.levels[l]);
    let clamp = l > 0;
    let hw = params.window_half.min(6) as i32;
    let side = (2 * hw + 1) as usize;
    let mut tpl = [[0.0f32; 3]; MAX_WIN * MAX_WIN];
    let (mut gxx, mut gyy, mut gxy) = (0.0f32, 0.0f32, 0.0f32);
    for j in 0..side {
        for i in 0..side {
            let (x, y) = (p.x + (i as i32 - hw) as f32, p.y + (j as i32 - hw) as f32);
            let c = a.sample(&la, x, y, clamp)?;
            let ix = 0.5 * (a.sample(&la, x + 1.0, y, clamp)? - a.sample(&la, x - 1.0, y, clamp)?);
            let iy = 0.5 * (a.sample(&la, x, y + 1.0, clamp)? - a.sample(&la, x, y - 1.0, clamp)?);
            tpl[j * side + i] = [c, ix, iy];
            gxx += ix * ix;
            gyy += iy * iy;
            gxy += ix * iy;
        }
    }
    let det = gxx * gyy - gxy * gxy;
    let area = (side * side) as f32;
    let (lmin, _, _) = geometry::solve::sym2_eigen(gxx, gxy, gyy);
    if !(det > 0.0) || lmin < params.min_eigen * area * 0.25 {
        // Too little texture at this scale: a coarse level passes the estimate on unchanged, the finest fails.
        return if l > 0 { Some(d) } else { None };
    }
    let inv = 1.0 / det;
    let mut last = f32::INFINITY;
    for _ in 0..params.max_iterations {
        let (mut bx, mut by) = (0.0f32, 0.0f32);
        for j in 0..side {
            for i in 0..side {
                let (x, y) = (p.x + d.x + (i as i32 - hw) as f32, p.y + d.y + (j as i32 - hw) as f32);
                let t = tpl[j * side + i];
                let e = b.sample(&lb, x, y, clamp)? - t[0];
                bx += e * t[1];
                by += e * t[2];
            }
        }
        let step = Vec2::new(-(gyy * bx - gxy * by) * inv, -(gxx * by - gxy * bx) * inv);
        d += step;
        last = step.norm();
        if last < params.epsilon_px {
            return Some(d);
        }
    }
    // Not converged within the limit: a coarse level only seeds the next one, and the quantised coarse images
    // often creep; at the finest level a track still moving by more than a tenth of a pixel is not trusted.
    if l > 0 || last < 0.1 { Some(d) } else { None }
}

/// Pyramidal Lucas-Kanade of the point `p` (level 0) from `a` to `b`, starting from `guess` (level 0).
fn track(a: &Pyramid, b: &Pyramid, p: Vec2, guess: Vec2, params: &FlowParams) -> Option<Vec2> {
    let levels = a.n.min(b.n);
    let top = levels - 1;
    let s = (1 << top) as f32;
    let mut d = guess * (1.0 / s);
    for l in (0..levels).rev() {
        let scale = (1 << l) as f32;
        let pl = Vec2::new((p.x + 0.5) / scale - 0.5, (p.y + 0.5) / scale - 0.5);
        d = lk_level(a, b, l, pl, d, params)?;
        if l > 0 {
            d = d * 2.0;
        }
    }
    // Beyond what the pyramid can reach from the guess, a result is not trusted.
    let reach = (params.window_half as f32 + 1.0) * (1 << levels) as f32;
    ((d - guess).norm() <= reach).then_some(d)
}

/// The rotational displacement (pixels) at pixel `p` for a small camera rotation `rot`.
fn rotational_px(camera: &CameraModel, p: Vec2, rot: Vec3) -> Vec2 {
    let n = camera.pixel_to_normalized(p);
    camera.normalized_to_pixel(n + rot_flow_at(n.x, n.y, rot)) - p
}

/// Adds a frame. The first frame only fills the workspace (returns `Ok(None)`); each later one is tracked
/// against the previous, with `predicted_rotation` (camera frame, rad, over the interval) seeding the tracks.
pub fn add_frame(
    img: &Gray8View<'_>,
    camera: &CameraModel,
    params: &FlowParams,
    predicted_rotation: Vec3,
    ws: &mut FlowWorkspace,
) -> Result<Option<FlowStats>, NoFlowReason> {
    if img.width() > FLOW_MAX_W
        || img.height() > FLOW_MAX_H
        || img.width() != camera.width as usize
        || img.height() != camera.height as usize
    {
        return Err(NoFlowReason::BadImageSize);
    }
    let next = 1 - ws.prev;
    ws.pyr[next].build(img, (params.levels as usize).clamp(1, MAX_LEVELS));
    if !ws.has_prev {
        ws.has_prev = true;
        ws.prev = next;
        return Ok(None);
    }
    let prev = ws.prev;
    ws.prev = next;
    let (a, b) = (&ws.pyr[prev], &ws.pyr[next]);
    if a.levels[0].w != b.levels[0].w || a.levels[0].h != b.levels[0].h {
        return Err(NoFlowReason::BadImageSize);
    }
    let n_sel = select_features(a, params, &mut ws.feats);
    if n_sel == 0 {
        return Err(NoFlowReason::NoTexture);
    }
    let mut n = 0;
    for k in 0..n_sel {
        let p = ws.feats[k];
        let guess = rotational_px(camera, p, predicted_rotation);
        let Some(d) = track(a, b, p, guess, params) else { continue };
        // Forward-backward: track back and require the start point again.
        let Some(back) = track(b, a, p + d, -d, params) else { continue };
        if (back + d).norm() > params.fb_max_px {
            continue;
        }
        ws.tracks[n] = (p, d);
        n += 1;
    }
    aggregate(&ws.tracks[..n], n_sel, camera, params, predicted_rotation, &mut ws.inlier, &mut ws.scratch)
        .map(Some)
}

/// Flow between two frames (a convenience over [`add_frame`]).
pub fn flow_between(
    prev: &Gray8View<'_>,
    next: &Gray8View<'_>,
    camera: &CameraModel,
    params: &FlowParams,
    predicted_rotation: Vec3,
    ws: &mut FlowWorkspace,
) -> Result<FlowStats, NoFlowReason> {
    ws.reset();
    add_frame(prev, camera, params, predicted_rotation, ws)?;
    add_frame(next, camera, params, predicted_rotation, ws)?.ok_or(NoFlowReason::TooFewTracks)
}

/// Median of a non-empty slice (mean of the middle two for even lengths); reorders the slice.
fn median_of(v: &mut [f32]) -> f32 {
    let m = v.len();
    let (lo, hi, _) = v.select_nth_unstable_by(m / 2, |a, b| a.total_cmp(b));
    if m % 2 == 1 { *hi } else { 0.5 * (*hi + lo.iter().copied().fold(f32::NEG_INFINITY, f32::max)) }
}

/// Affine flow fit with MAD rejection, then the inliers' statistics.
fn aggregate(
    tracks: &[(Vec2, Vec2)],
    selected: usize,
    camera: &CameraModel,
    params: &FlowParams,
    predicted_rotation: Vec3,
    inlier: &mut [bool; MAX_FEATURES],
    scratch: &mut [f32; MAX_FEATURES],
) -> Result<FlowStats, NoFlowReason> {
    let n = tracks.len();
    if n < params.min_tracks as usize {
        return Err(NoFlowReason::TooFewTracks);
    }
    let f = camera.focal_px();
    // Normalised positions and displacements.
    let mut pos = [Vec2::ZERO; MAX_FEATURES];
    let mut disp = [Vec2::ZERO; MAX_FEATURES];
    for (k, (p, d)) in tracks.iter().enumerate() {
        let a = camera.pixel_to_normalized(*p);
        pos[k] = a;
        disp[k] = camera.pixel_to_normalized(*p + *d) - a;
    }
    inlier[..n].fill(true);
    let mut res = [0.0f32; MAX_FEATURES];
    let mut model = [[0.0f32; 3]; 2];
    for _ in 0..3 {
        // Least squares of disp = c + A (pos - centroid) per axis, over the inliers.
        let m = inlier[..n].iter().filter(|k| **k).count();
        if m < params.min_tracks as usize {
            return Err(NoFlowReason::TooFewTracks);
        }
        let mut c = Vec2::ZERO;
        for k in (0..n).filter(|k| inlier[*k]) {
            c += pos[k];
        }
        c = c * (1.0 / m as f32);
        let mut h = [[0.0f32; 3]; 3];
        let mut g = [[0.0f32; 3]; 2];
        for k in (0..n).filter(|k| inlier[*k]) {
            let r = [1.0, pos[k].x - c.x, pos[k].y - c.y];
            for i in 0..3 {
                for j in 0..3 {
                    h[i][j] += r[i] * r[j];
                }
                g[0][i] += r[i] * disp[k].x;
                g[1][i] += r[i] * disp[k].y;
            }
        }
        for axis in 0..2 {
            let mut hh = h;
            let mut b = g[axis];
            // Regularise the slopes a little: with features in one region the affine terms are weak.
            hh[1][1] += 1e-6 * m as f32;
            hh[2][2] += 1e-6 * m as f32;
            if !geometry::solve::cholesky_solve(&mut hh, &mut b, 3) {
                return Err(NoFlowReason::TooFewTracks);
            }
            model[axis] = b;
        }
        let resid = |k: usize| {
            let r = [1.0, pos[k].x - c.x, pos[k].y - c.y];
            let px = model[0][0] * r[0] + model[0][1] * r[1] + model[0][2] * r[2];
            let py = model[1][0] * r[0] + model[1][1] * r[1] + model[1][2] * r[2];
            (disp[k] - Vec2::new(px, py)).norm()
        };
        for k in 0..n {
            res[k] = resid(k);
        }
        scratch[..n].copy_from_slice(&res[..n]);
        // The residual's norm is Rayleigh-distributed for Gaussian noise: median = 1.1774 sigma per axis.
        let sigma = median_of(&mut scratch[..n]) / 1.1774;
        let thresh = (params.outlier_sigmas * sigma).max(0.1 / f);
        let mut changed = false;
        for k in 0..n {
            let ok = res[k] <= thresh;
            changed |= ok != inlier[k];
            inlier[k] = ok;
        }
        if !changed {
            break;
        }
    }
    let idx = |k: &usize| inlier[*k];
    let m = (0..n).filter(idx).count();
    if m < params.min_tracks as usize {
        return Err(NoFlowReason::TooFewTracks);
    }
    let inv = 1.0 / m as f32;
    let mut mp = Vec2::ZERO;
    let mut sq = [0.0f32; 3];
    for k in (0..n).filter(idx) {
        mp += pos[k];
        sq[0] += pos[k].x * pos[k].x;
        sq[1] += pos[k].y * pos[k].y;
        sq[2] += pos[k].x * pos[k].y;
    }
    let mut rss = 0.0f32;
    for k in (0..n).filter(idx) {
        rss += res[k] * res[k];
    }
    // Medians per axis: of the displacement less the predicted rotational flow (normalised), and of the raw
    // displacement (pixels).
    let mut median = |value: &dyn Fn(usize) -> f32| {
        for (j, k) in (0..n).filter(idx).enumerate() {
            scratch[j] = value(k);
        }
        median_of(&mut scratch[..m])
    };
    let derot = |k: usize| disp[k] - rot_flow_at(pos[k].x, pos[k].y, predicted_rotation);
    let flow = Vec2::new(median(&|k| derot(k).x), median(&|k| derot(k).y));
    let med = Vec2::new(median(&|k| tracks[k].1.x), median(&|k| tracks[k].1.y));
    let residual_rms = libm::sqrtf(rss * inv);
    let quality = m as f32 / selected.max(1) as f32;
    if quality < params.min_quality || residual_rms * f > params.max_residual_px {
        return Err(NoFlowReason::Inconsistent);
    }
    Ok(FlowStats {
        flow,
        predicted_rotation,
        mean_pos: mp * inv,
        mean_sq: sq.map(|v| v * inv),
        inliers: m as u16,
        selected: selected as u16,
        residual_rms,
        median_flow_px: med,
        quality,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 160;
    const H: usize = 120;

    fn cam() -> CameraModel {
        CameraModel {
            width: W as u16,
            height: H as u16,
            fx: 139.0,
            fy: 139.0,
            cx: 79.5,
            cy: 59.5,
            distortion: Default::default(),
        }
    }

    /// A smooth random texture sampled at (x + dx, y + dy) with exact bilinear-free evaluation (sum of
    /// sinusoids), so that sub-pixel shifts are exact.
    fn texture(dx: f32, dy: f32, contrast: f32) -> Vec<u8> {
        let mut img = vec![0u8; W * H];
        let waves = [
            (0.31f32, 0.17f32, 0.0f32),
            (-0.13, 0.41, 1.0),
            (0.57, -0.23, 2.0),
            (0.07, 0.11, 0.5),
            (0.21, 0.29, 3.0),
            (-0.45, 0.06, 4.0),
        ];
        for y in 0..H {
            for x in 0..W {
                let (u, v) = (x as f32 + dx, y as f32 + dy);
                let mut s = 0.0;
                for (a, b, ph) in waves {
                    s += (a * u + b * v + ph).sin();
                }
                img[y * W + x] = (128.0 + contrast * 20.0 * s).round().clamp(0.0, 255.0) as u8;
            }
        }
        img
    }

    fn run(a: &[u8], b: &[u8], pred: Vec3) -> Result<FlowStats, NoFlowReason> {
        let mut ws = Box::new(FlowWorkspace::new());
        let va = Gray8View::packed(a, W, H).unwrap();
        let vb = Gray8View::packed(b, W, H).unwrap();
        flow_between(&va, &vb, &cam(), &FlowParams::default(), pred, &mut ws)
    }

    #[test]
    fn sub_pixel_shift_is_recovered() {
        for &(sx, sy) in &[(0.37f32, -0.21f32), (1.6, 0.45), (-2.3, 3.1), (0.0, 0.0)] {
            // Content moves by (sx, sy): the next frame at x shows what the previous one showed at x - s.
            let a = texture(0.0, 0.0, 1.0);
            let b = texture(-sx, -sy, 1.0);
            let s = run(&a, &b, Vec3::ZERO).unwrap();
            let f = s.median_flow_px;
            assert!((f.x - sx).abs() < 0.05 && (f.y - sy).abs() < 0.05, "shift ({sx}, {sy}): measured {f:?}");
            let m = s.flow * 139.0;
            assert!((m.x - sx).abs() < 0.05 && (m.y - sy).abs() < 0.05, "robust flow {m:?}");
            assert!(s.quality > 0.8 && s.inliers >= 30, "{s:?}");
        }
    }

    #[test]
    fn blank_floor_has_no_flow() {
        let a = texture(0.0, 0.0, 0.0);
        assert_eq!(run(&a, &a, Vec3::ZERO).unwrap_err(), NoFlowReason::NoTexture);
    }

    #[test]
    fn shifts_beyond_reach_are_rejected() {
        // 3 levels, window 9: reach about (4 + 1) * 8 = 40 px. A 60 px jump of a periodic-ish texture must
        // not come back as a small wrapped flow.
        let a = texture(0.0, 0.0, 1.0);
        let b = texture(-60.0, 0.0, 1.0);
        match run(&a, &b, Vec3::ZERO) {
            Err(e) => assert!(matches!(e, NoFlowReason::TooFewTracks | NoFlowReason::Inconsistent), "{e:?}"),
            Ok(s) => panic!("a 60 px shift gave a flow: {s:?}"),
        }
    }

    #[test]
    fn a_prediction_extends_the_reach() {
        // A 60 px shift is beyond the pyramid's reach without a guess; a guess 3 px off brings it back.
        let a = texture(0.0, 0.0, 1.0);
        let b = texture(60.0, -10.0, 1.0);
        let (va, vb) = (Gray8View::packed(&a, W, H).unwrap(), Gray8View::packed(&b, W, H).unwrap());
        let mut ws = Box::new(FlowWorkspace::new());
        ws.pyr[0].build(&va, 3);
        ws.pyr[1].build(&vb, 3);
        let params = FlowParams::default();
        let p = Vec2::new(110.0, 60.0);
        let truth = Vec2::new(-60.0, 10.0);
        let near = |d: Option<Vec2>| d.is_some_and(|d| (d - truth).norm() < 0.05);
        assert!(!near(track(&ws.pyr[0], &ws.pyr[1], p, Vec2::ZERO, &params)));
        let d = track(&ws.pyr[0], &ws.pyr[1], p, truth + Vec2::new(2.0, -2.0), &params);
        assert!(near(d), "{d:?}");
    }

    #[test]
    fn velocity_from_translation_and_rotation() {
        // Level camera 1 m above the floor moving at 0.5 m/s along its x for 20 ms: translational flow
        // -0.01 (normalised) everywhere, plus a rotation whose flow the derotation must remove.
        let stats = FlowStats {
            flow: Vec2::ZERO,
            predicted_rotation: Vec3::new(0.012, -0.018, 0.0),
            mean_pos: Vec2::new(0.1, -0.05),
            mean_sq: [0.05, 0.03, -0.004],
            inliers: 40,
            selected: 48,
            residual_rms: 0.001,
            median_flow_px: Vec2::ZERO,
            quality: 0.8,
        };
        let rot = Vec3::new(0.01, -0.02, 0.005);
        let mut s = stats;
        // The tracker removed the flow of its predicted rotation; the velocity corrects for the difference.
        s.flow = Vec2::new(-0.01, 0.0) + stats.rotational_flow(rot - stats.predicted_rotation);
        let v = s.velocity(rot, 0.02, 1.0, Vec3::Z, 0.0, 0.0).unwrap();
        assert!((v.velocity_cam_m_s.x - 0.5).abs() < 1e-4 && v.velocity_cam_m_s.y.abs() < 1e-4, "{v:?}");
        assert!(v.std_m_s > 0.0);
        // Tilted floor: depth at the mean position differs from the range on the axis.
        let n = Vec3::new(0.2, 0.0, 0.98).normalized().unwrap();
        let v2 = s.velocity(rot, 0.02, 1.0, n, 0.0, 0.0).unwrap();
        assert!((v2.velocity_cam_m_s.x - 0.5).abs() > 0.005);
        assert!(s.velocity(rot, 0.0, 1.0, Vec3::Z, 0.0, 0.0).is_none());
    }
}
