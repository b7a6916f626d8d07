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
use geometry::{Mat3, Quat, Vec2, Vec3};

mod aggregate;
mod lk;
mod pyramid;
mod repetition;
mod search;
use aggregate::aggregate;
use lk::{LkScratch, lk_level, track};
use pyramid::{Level, Pyramid};
pub use repetition::Repetition;

/// Pyramid levels at most.
pub const MAX_LEVELS: usize = 5;
/// Largest frame the flow workspace holds.
pub const FLOW_MAX_W: usize = 640;
/// Largest frame height the flow workspace holds.
pub const FLOW_MAX_H: usize = 480;
/// Features tracked at most.
pub const MAX_FEATURES: usize = 512;
/// Half side of the tracking window at most.
pub const MAX_WINDOW_HALF: u8 = 20;
const MAX_WIN: usize = 2 * MAX_WINDOW_HALF as usize + 1; // window side at most

/// Why a frame pair gave no flow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
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
    /// The floor repeats within the tracking's reach (tiles, a grid, stripes): a displacement and the same
    /// displacement less one repetition match equally well, so the flow may be an alias.
    RepeatingTexture,
}

impl NoFlowReason {
    /// Short explanation.
    pub fn describe(&self) -> &'static str {
        match self {
            NoFlowReason::BadImageSize => "the frames differ in size or exceed 640x480",
            NoFlowReason::NoTexture => "the floor shows no texture to track",
            NoFlowReason::TooFewTracks => {
                "too few features could be tracked (motion beyond reach, blur, or occlusion)"
            }
            NoFlowReason::Inconsistent => {
                "the tracks disagree on one motion of the floor (parts of the view moving differently, or motion \
                 beyond reach on a repetitive floor)"
            }
            NoFlowReason::RepeatingTexture => {
                "the floor repeats within the tracking's reach, so the flow could be an alias"
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
            NoFlowReason::RepeatingTexture => "repeating_texture",
        }
    }
}

/// Tuning of the flow.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FlowParams {
    /// Pyramid levels (1 to [`MAX_LEVELS`]).
    pub levels: u8,
    /// Half side of the tracking window (window `2h + 1` pixels, h up to [`MAX_WINDOW_HALF`]).
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
    /// A frame whose texture matches itself, at an offset within the tracking's reach, with a mean squared
    /// difference below this fraction of the typical one repeats (tiles, grids): its pairs are refused
    /// (`flow::repetition`). 0 turns the check off.
    pub max_repetition_ratio: f32,
    /// Search the whole frame's displacement within this many pixels of the predicted rotation's on the
    /// coarsest level before tracking (`flow::search`), for motions beyond Lucas-Kanade's reach; 0: off.
    pub search_px: f32,
    /// Estimate a brightness gain and offset between each pair of windows with the displacement (vignetting,
    /// exposure changes between frames, uneven light).
    pub gain_offset: bool,
    /// Smooth the frames with a 3x3 binomial filter first (recommended unless the camera's images are
    /// already soft: it removes most of bilinear interpolation's sub-pixel bias).
    pub presmooth: bool,
}

impl Default for FlowParams {
    fn default() -> Self {
        Self {
            levels: 2,
            window_half: 4,
            max_iterations: 12,
            epsilon_px: 0.01,
            grid: [8, 6],
            min_eigen: 8.0,
            fb_max_px: 0.3,
            min_tracks: 8,
            outlier_sigmas: 3.0,
            min_quality: 0.35,
            max_residual_px: 0.5,
            max_repetition_ratio: 0.25,
            presmooth: true,
            gain_offset: false,
            search_px: 0.0,
        }
    }
}

impl FlowParams {
    /// The defaults scaled for a `width x height` frame: the defaults are for 160x120.
    pub fn for_image(width: u16, height: u16) -> Self {
        let d = Self::default();
        // The frame's scale over 160x120 in whole octaves (a 200x150 frame is still 160x120's).
        let k = (width as f32 / 160.0).max(height as f32 / 120.0);
        let octaves = if k >= 1.0 { libm::floorf(libm::log2f(k) + 0.25) as u8 } else { 0 };
        if octaves == 0 {
            return d;
        }
        let scale = (1u32 << octaves.min(7)) as f32;
        Self {
            // A level more than the octaves: the reach, `(window_half + 1) 2^levels`, a third of the width
            // or more (320x240: 176 px, 640x480: 672 px).
            levels: (d.levels + 1 + octaves).min(MAX_LEVELS as u8),
            // Half windows of 10 px at 320x240 (OpenCV's 21x21) and 20 px at 640x480: a window over the same
            // part of the floor, a little wider than 160x120's.
            window_half: ((5.0 * scale) as u8).min(MAX_WINDOW_HALF),
            // Twice the cells per axis (192 features at most): the flow's noise falls with their number.
            grid: [2 * d.grid[0], 2 * d.grid[1]],
            // The same texture per unit of floor: gradients per pixel fall with the scale.
            min_eigen: d.min_eigen / (scale * scale),
            // Vignetting's static brightness read as motion: per-pair flow error p90 at 320x240 0.043 -> 0.028 px
            // (tests/tests/flow_opencv.rs).
            gain_offset: true,
            // Reach: two fifths of the width searched whole (a third of it asked for).
            search_px: 0.4 * width as f32,
            ..d
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
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
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
    /// Features selected whose predicted position in the later frame was in view (tracked).
    pub selected: u16,
    /// RMS residual of the inliers about the affine fit (normalised units).
    pub residual_rms: f32,
    /// Median raw displacement of the inliers (pixels), for reports.
    pub median_flow_px: Vec2,
    /// Quality, 0 (unusable) to 1: the fraction of the features tracked (selected and in view) that became
    /// inliers.
    pub quality: f32,
}

/// What the last pair came to, also when it was refused: the numbers behind a [`NoFlowReason`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PairCounts {
    /// Features selected in the earlier frame.
    pub selected: u16,
    /// Of those, the ones whose predicted position was in view in the later frame (tracked).
    pub in_view: u16,
    /// Tracks that converged and came back in the forward-backward check.
    pub tracked: u16,
    /// Inliers of the flow field's fit (0 before a fit).
    pub inliers: u16,
    /// RMS residual of the inliers about the fit (px; NaN before a fit).
    pub residual_px: f32,
}

impl PairCounts {
    /// Inliers over the features in view (the flow's quality).
    pub fn quality(&self) -> f32 {
        self.inliers as f32 / self.in_view.max(1) as f32
    }
}

/// A velocity from the flow.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
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
        // trans = (pos T_z - T_xy) / (Z - T_z)  =>  T_xy = pos T_z - trans (Z - T_z).
        let z = 1.0 / inv_z;
        let t = self.mean_pos * tz - trans * (z - tz);
        let v = t * (1.0 / dt);
        // Noise of the median: per-track residual (or the noise floor) times 1.25 over sqrt(inliers).
        let per_track = self.residual_rms.max(pixel_sigma);
        let std = 1.25 * per_track * z / dt / libm::sqrtf(self.inliers as f32);
        Some(FlowVelocity { velocity_cam_m_s: v, std_m_s: std })
    }
}

/// Buffers of the flow (about 0.9 MB: two pyramids of up to 640x480). One per downward camera.
pub struct FlowWorkspace {
    pyr: [Pyramid; 2],
    prev: usize,
    has_prev: bool,
    feats: [Vec2; MAX_FEATURES],
    tracks: [(Vec2, Vec2); MAX_FEATURES],
    n_tracks: usize,
    inlier: [bool; MAX_FEATURES],
    scratch: [f32; MAX_FEATURES],
    lk: LkScratch,
    rep_scratch: repetition::Scratch,
    repetition: Option<Repetition>,
    counts: PairCounts,
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
            n_tracks: 0,
            inlier: [false; MAX_FEATURES],
            scratch: [0.0; MAX_FEATURES],
            lk: LkScratch::new(),
            rep_scratch: repetition::Scratch::new(),
            repetition: None,
            counts: PairCounts { selected: 0, in_view: 0, tracked: 0, inliers: 0, residual_px: f32::NAN },
        }
    }

    /// Forgets the previous frame.
    pub fn reset(&mut self) {
        self.has_prev = false;
        self.counts = PairCounts { residual_px: f32::NAN, ..PairCounts::default() };
        self.repetition = None;
        self.n_tracks = 0;
    }

    /// The tracks of the last pair, for display: each feature's position in the earlier frame (px), its
    /// displacement to the later one (px) and whether the velocity used it (an inlier). Empty after a first
    /// frame, a reset, or a pair refused before tracking.
    pub fn last_tracks(&self) -> impl Iterator<Item = (Vec2, Vec2, bool)> + '_ {
        self.tracks[..self.n_tracks].iter().zip(&self.inlier).map(|(&(p, d), &ok)| (p, d, ok))
    }

    /// The counts of the last pair (zero after a first frame or a reset): how many features were selected, in
    /// view, tracked and inliers, and the fit's residual, which say in numbers why a pair was refused.
    pub fn last_counts(&self) -> PairCounts {
        self.counts
    }

    /// The repetition that made the last pair [`NoFlowReason::RepeatingTexture`] (None after any other
    /// result): the offset at which the floor repeats and how well.
    pub fn repetition(&self) -> Option<Repetition> {
        self.repetition
    }
}

/// Selects up to one feature per grid cell on pyramid level 1 (or 0 for one-level pyramids): the pixel with
/// the largest minimum eigenvalue of its 3x3 structure tensor, above `min_eigen`. Returns level-0 positions.
///
/// One pass over the level with a rolling window of three rows of gradient products, so each pixel's
/// gradient is computed once.
fn select_features(p: &Pyramid, params: &FlowParams, out: &mut [Vec2; MAX_FEATURES]) -> usize {
    let li = if p.n > 1 { 1 } else { 0 };
    let l = p.levels[li];
    let scale = (1 << li) as f32;
    let (gx, gy) = (params.grid[0].max(1) as usize, params.grid[1].max(1) as usize);
    let margin = 2 + (params.window_half as usize + 1) / (1 << li);
    let (w, h) = (l.w, l.h);
    if w <= 2 * margin || h <= 2 * margin || gx * gy > MAX_FEATURES {
        return 0;
    }
    // Best score and position per cell.
    let mut best = [(params.min_eigen * 9.0, u16::MAX, 0u16); MAX_FEATURES];
    // Rolling rows of (Ixx, Iyy, Ixy) for rows y-1, y, y+1; row r lives in slot r % 3.
    let mut rows = [[[0.0f32; 3]; FLOW_MAX_W]; 3];
    let d = &p.data[l.off..l.off + w * h];
    let products = |y: usize, out: &mut [[f32; 3]; FLOW_MAX_W]| {
        for x in 1..w - 1 {
            let ix = 0.5 * (d[y * w + x + 1] as f32 - d[y * w + x - 1] as f32);
            let iy = 0.5 * (d[(y + 1) * w + x] as f32 - d[(y - 1) * w + x] as f32);
            out[x] = [ix * ix, iy * iy, ix * iy];
        }
    };
    let mut col = [[0.0f32; 3]; FLOW_MAX_W];
    let y_first = margin - 1;
    let y_last = h - margin; // exclusive end of the centre rows, plus one row below
    for y in y_first..=y_last {
        products(y, &mut rows[y % 3]);
        if y < y_first + 2 {
            continue;
        }
        let yc = y - 1;
        let cy = (yc * gy / h).min(gy - 1);
        let (r0, r1, r2) = (&rows[(yc - 1) % 3], &rows[yc % 3], &rows[(yc + 1) % 3]);
        for x in margin - 1..w - margin + 1 {
            for k in 0..3 {
                col[x][k] = r0[x][k] + r1[x][k] + r2[x][k];
            }
        }
        for x in margin..w - margin {
            let sxx = col[x - 1][0] + col[x][0] + col[x + 1][0];
            let syy = col[x - 1][1] + col[x][1] + col[x + 1][1];
            let sxy = col[x - 1][2] + col[x][2] + col[x + 1][2];
            let half_tr = 0.5 * (sxx + syy);
            let cell = cy * gx + (x * gx / w).min(gx - 1);
            // The smaller eigenvalue is at most half the trace: most pixels are out before the square root.
            if half_tr <= best[cell].0 {
                continue;
            }
            let half_diff = 0.5 * (sxx - syy);
            let lmin = half_tr - libm::sqrtf(half_diff * half_diff + sxy * sxy);
            if lmin > best[cell].0 {
                best[cell] = (lmin, x as u16, yc as u16);
            }
        }
    }
    let mut n = 0;
    for &(_, x, y) in best.iter().take(gx * gy) {
        if x != u16::MAX {
            // Integer level-0 positions: the template is then sampled without interpolation (which would
            // smooth it unlike the target and bias the sub-pixel result).
            out[n] = Vec2::new(x as f32 * scale, y as f32 * scale);
            n += 1;
        }
    }
    n
}

/// Where a point seen at normalised `n` appears after the camera rotates by `rot` (exact: `pi(R^T n)`).
#[inline]
fn rotate_point(n: Vec2, rot: &Mat3) -> Option<Vec2> {
    let v = rot.tmul_vec(Vec3::new(n.x, n.y, 1.0));
    (v.z > 1e-3).then(|| Vec2::new(v.x / v.z, v.y / v.z))
}

/// Undoes the camera's rotation `rot` for a point seen at normalised `n` after it (exact: `pi(R n)`).
#[inline]
fn derotate_point(n: Vec2, rot: &Mat3) -> Option<Vec2> {
    let v = rot.mul_vec(Vec3::new(n.x, n.y, 1.0));
    (v.z > 1e-3).then(|| Vec2::new(v.x / v.z, v.y / v.z))
}

/// The rotational displacement (pixels) at pixel `p` for a camera rotation `rot`.
fn rotational_px(camera: &CameraModel, p: Vec2, rot: &Mat3) -> Vec2 {
    let n = camera.pixel_to_normalized(p);
    match rotate_point(n, rot) {
        Some(m) => camera.normalized_to_pixel(m) - p,
        None => Vec2::ZERO,
    }
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
    ws.n_tracks = 0;
    ws.counts = PairCounts { residual_px: f32::NAN, ..PairCounts::default() };
    if img.width() > FLOW_MAX_W
        || img.height() > FLOW_MAX_H
        || img.width() != camera.width as usize
        || img.height() != camera.height as usize
    {
        return Err(NoFlowReason::BadImageSize);
    }
    let next = 1 - ws.prev;
    ws.pyr[next].build(img, (params.levels as usize).clamp(1, MAX_LEVELS), params.presmooth);
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
    ws.repetition = None;
    let n_sel = select_features(a, params, &mut ws.feats);
    ws.counts.selected = n_sel as u16;
    if n_sel == 0 {
        return Err(NoFlowReason::NoTexture);
    }
    let mut n = 0;
    let rot = Quat::from_rotvec(predicted_rotation).to_mat3();
    // The whole frame's displacement beyond the predicted rotation's (`flow::search`), when searched.
    let mut extra = Vec2::ZERO;
    let mut max_levels = MAX_LEVELS;
    if params.search_px > 0.0 {
        let centre = Vec2::new(camera.cx, camera.cy);
        let predicted = rotational_px(camera, centre, &rot);
        if let Some(shift) = search::whole_frame_shift(a, b, predicted, params.search_px) {
            extra = shift - predicted;
            // Within half a pixel of the coarsest level: Lucas-Kanade starts a level below it (a pair at
            // 640x480 then costs 4 levels' tracking instead of 5).
            max_levels = a.n.min(b.n).saturating_sub(1);
        }
    }
    // Features whose guessed end lies outside the later frame have left the view: they are neither tracked nor
    // counted in the quality (a large motion is not inconsistent for losing them).
    let margin = params.window_half.min(MAX_WINDOW_HALF) as f32 + 1.0;
    let (w, h) = (b.levels[0].w as f32, b.levels[0].h as f32);
    let mut n_view = 0;
    for k in 0..n_sel {
        let p = ws.feats[k];
        let guess = rotational_px(camera, p, &rot) + extra;
        let end = p + guess;
        if !(end.x >= margin && end.y >= margin && end.x <= w - 1.0 - margin && end.y <= h - 1.0 - margin) {
            continue;
        }
        n_view += 1;
        let Some(d) = track(a, b, p, guess, max_levels, params, &mut ws.lk) else { continue };
        // Forward-backward: track the end point back (at full resolution, from the forward result) and
        // require the start point again.
        let Some(back) = lk_level(b, a, 0, p + d, -d, params, &mut ws.lk) else { continue };
        if (back + d).norm() > params.fb_max_px {
            continue;
        }
        ws.tracks[n] = (p, d);
        n += 1;
    }
    ws.n_tracks = n;
    ws.counts.in_view = n_view as u16;
    ws.counts.tracked = n as u16;
    // A pair refused by the aggregation keeps no inliers.
    ws.inlier[..n].fill(false);
    let stats = aggregate(
        &ws.tracks[..n],
        n_view,
        camera,
        params,
        predicted_rotation,
        &mut ws.inlier,
        &mut ws.scratch,
        &mut ws.counts,
    )?;
    // On a repeating floor a flow of a sizeable fraction of the repetition may be the alias of a longer
    // motion (`flow::repetition`); a small one is not (its alias would be a motion of most of a repetition).
    // Repetitions are at least `MIN_OFFSET_PX` long: a flow shorter than the refused fraction of that cannot be
    // refused, and the search is skipped (a hovering vehicle's pairs).
    let flow_px = stats.flow.norm() * camera.focal_px();
    if flow_px >= repetition::ALIAS_FRACTION * repetition::MIN_OFFSET_PX
        && let Some(rep) = repetition::find(&ws.pyr[prev], params, &mut ws.rep_scratch)
        && flow_px >= repetition::ALIAS_FRACTION * rep.offset_px.norm()
    {
        ws.repetition = Some(rep);
        return Err(NoFlowReason::RepeatingTexture);
    }
    Ok(Some(stats))
}

/// The flow statistics of given tracks (pixel position in the earlier frame, displacement in pixels), as
/// [`add_frame`] computes them from its own tracks: for simulations that produce tracks analytically and for
/// tests. At most [`MAX_FEATURES`] tracks are used.
pub fn stats_from_tracks(
    tracks: &[(Vec2, Vec2)],
    selected: usize,
    camera: &CameraModel,
    params: &FlowParams,
    predicted_rotation: Vec3,
) -> Result<FlowStats, NoFlowReason> {
    let n = tracks.len().min(MAX_FEATURES);
    let mut inlier = [false; MAX_FEATURES];
    let mut scratch = [0.0f32; MAX_FEATURES];
    let mut counts = PairCounts::default();
    aggregate(
        &tracks[..n],
        selected.max(n),
        camera,
        params,
        predicted_rotation,
        &mut inlier,
        &mut scratch,
        &mut counts,
    )
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

#[cfg(test)]
mod large_frame_tests;
#[cfg(test)]
mod tests;
