//! What the detector measures in one frame, in a compact form that the pose solver consumes and that can
//! cross the radio link (a few dozen floats instead of an image).
use crate::camera::CameraModel;
use crate::target::Corner;
use geometry::{Vec2, Vec3};

/// Sufficient statistics of the sub-pixel points measured along one edge, in normalised undistorted image
/// coordinates.
///
/// For any line with unit normal `m` and offset `d`, the sum of squared point-to-line distances of the
/// measured points is `N (m.c + d)^2 + N s^2 (m.t)^2 + N r^2 (m.n)^2`, where `c` is the centroid, `n` the
/// fitted normal, `t` the fitted direction, `s` the spread along the edge and `r` the residual RMS. The
/// pose solver minimises exactly that, without keeping the points.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EdgeStats {
    /// Centroid of the points (normalised coordinates).
    pub centroid: Vec2,
    /// Unit normal of the best-fit line (normalised coordinates).
    pub normal: Vec2,
    /// Number of points (inliers of the robust fit).
    pub count: u16,
    /// RMS spread of the points along the line (normalised units).
    pub spread: f32,
    /// RMS distance of the points from the best-fit line (normalised units).
    pub rms: f32,
}

impl EdgeStats {
    /// The best-fit line as homogeneous coefficients `(a, b, c)` with `a x + b y + c = 0` in normalised
    /// coordinates and `(a, b)` a unit vector.
    pub fn line(&self) -> Vec3 {
        Vec3::new(self.normal.x, self.normal.y, -self.normal.dot(self.centroid))
    }

    /// Unit direction of the best-fit line.
    pub fn direction(&self) -> Vec2 {
        self.normal.perp()
    }

    /// The points' extreme positions along the line (assuming a uniform spread: centroid +- sqrt(3) spread).
    pub fn extent(&self) -> (Vec2, Vec2) {
        let h = self.direction() * (1.732_050_8 * self.spread);
        (self.centroid - h, self.centroid + h)
    }

    /// Builds the statistics from points in normalised coordinates. Returns `None` for fewer than two points
    /// or coincident points.
    pub fn from_points(points: impl Iterator<Item = Vec2> + Clone) -> Option<EdgeStats> {
        let mut n = 0u32;
        let mut sum = Vec2::ZERO;
        let mut origin = None;
        for p in points.clone() {
            let o = *origin.get_or_insert(p);
            sum += p - o;
            n += 1;
        }
        let o = origin?;
        if n < 2 {
            return None;
        }
        let c = o + sum * (1.0 / n as f32);
        let (mut sxx, mut sxy, mut syy) = (0.0f32, 0.0f32, 0.0f32);
        for p in points.clone() {
            let d = p - c;
            sxx += d.x * d.x;
            sxy += d.x * d.y;
            syy += d.y * d.y;
        }
        let (_, l_large, v) = geometry::solve::sym2_eigen(sxx, sxy, syy);
        if !(l_large > 0.0) {
            return None;
        }
        let normal = Vec2::new(v[0], v[1]);
        let dir = normal.perp();
        let (mut saa, mut sbb) = (0.0f32, 0.0f32);
        for p in points {
            let d = p - c;
            let a = dir.dot(d);
            let b = normal.dot(d);
            saa += a * a;
            sbb += b * b;
        }
        let inv = 1.0 / n as f32;
        Some(EdgeStats {
            centroid: c,
            normal,
            count: n.min(u16::MAX as u32) as u16,
            spread: libm::sqrtf(saa * inv),
            rms: libm::sqrtf(sbb * inv),
        })
    }
}

/// One frame's measurement of the line: its two long edges, whichever ends are in view, and the corners.
///
/// Ends: when the vehicle faces the wall, the line's `x_start` end appears on the right of the image and
/// its `x_end` end on the left (world `+x` runs to the image's left).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LineObservation {
    /// The upper long edge (`BC`).
    pub top: EdgeStats,
    /// The lower long edge (`AD`).
    pub bottom: EdgeStats,
    /// The short edge at `x_start` (`AB`), when that end is in view.
    pub start_end: Option<EdgeStats>,
    /// The short edge at `x_end` (`DC`), when that end is in view.
    pub finish_end: Option<EdgeStats>,
}

impl LineObservation {
    /// Number of real corners (two per visible end).
    pub fn real_corners(&self) -> u8 {
        2 * (self.start_end.is_some() as u8 + self.finish_end.is_some() as u8)
    }

    /// The measured image position (px) of a corner: the intersection of the fitted edges, `None` when its
    /// end is not in view.
    pub fn corner_px(&self, camera: &CameraModel, c: Corner) -> Option<Vec2> {
        let (long, end) = match c {
            Corner::A => (self.bottom, self.start_end?),
            Corner::B => (self.top, self.start_end?),
            Corner::C => (self.top, self.finish_end?),
            Corner::D => (self.bottom, self.finish_end?),
        };
        let p = long.line().cross(end.line());
        if p.z.abs() < 1e-12 {
            return None;
        }
        Some(camera.normalized_to_pixel(Vec2::new(p.x / p.z, p.y / p.z)))
    }

    /// All four corners in the order A, B, C, D.
    pub fn corners_px(&self, camera: &CameraModel) -> [Option<Vec2>; 4] {
        Corner::ALL.map(|c| self.corner_px(camera, c))
    }
}

/// Projects the line seen by a camera at a known pose into the observation a perfect detector would give:
/// points every `spacing_px` pixels along the visible part of each edge (inside the image by `margin_px`
/// and in front of the camera), each moved across its edge by `noise()` pixels. An end counts as in view
/// only when both of its corners are. Returns `None` when a long edge has fewer than two visible points.
///
/// `camera_from_world` is `R_CW`, `camera_center` the camera centre in the world frame.
pub fn project_observation(
    camera: &CameraModel,
    target: &crate::target::LineTarget,
    camera_from_world: &geometry::Mat3,
    camera_center: Vec3,
    margin_px: f32,
    spacing_px: f32,
    mut noise: impl FnMut() -> f32,
) -> Option<LineObservation> {
    use crate::target::Edge;
    let project = |p: Vec3| -> Option<(Vec2, Vec2)> {
        let x = camera_from_world.mul_vec(p - camera_center);
        if x.z <= 1e-3 {
            return None;
        }
        let n = Vec2::new(x.x / x.z, x.y / x.z);
        let px = camera.normalized_to_pixel(n);
        camera.contains(px, margin_px).then_some((n, px))
    };
    let visible = |c: Corner| project(target.corner(c)).is_some();
    let f = camera.focal_px();
    let mut stats = [None; 4];
    for e in Edge::ALL {
        let is_end = matches!(e, Edge::StartEnd | Edge::FinishEnd);
        let (ca, cb) = target.edge_corners(e);
        if is_end && !(visible(ca) && visible(cb)) {
            continue;
        }
        let (p1, p2) = (target.corner(ca), target.corner(cb));
        let at = |t: f32| project(p1 + (p2 - p1) * t);
        // Visible interval of the edge: a coarse scan, then bisection on each boundary.
        const COARSE: usize = 64;
        let mut first = None;
        let mut last = None;
        for i in 0..=COARSE {
            if at(i as f32 / COARSE as f32).is_some() {
                first.get_or_insert(i);
                last = Some(i);
            }
        }
        let (Some(first), Some(last)) = (first, last) else {
            if is_end {
                continue;
            }
            return None;
        };
        let refine = |mut inside: f32, mut outside: f32| {
            for _ in 0..20 {
                let m = 0.5 * (inside + outside);
                if at(m).is_some() { inside = m } else { outside = m }
            }
            inside
        };
        let t0 = if first == 0 {
            0.0
        } else {
            refine(first as f32 / COARSE as f32, (first - 1) as f32 / COARSE as f32)
        };
        let t1 = if last == COARSE {
            1.0
        } else {
            refine(last as f32 / COARSE as f32, (last + 1) as f32 / COARSE as f32)
        };
        let (Some((_, a)), Some((_, b))) = (at(t0), at(t1)) else { continue };
        let mut pts = [Vec2::ZERO; 512];
        let count = (((b - a).norm() / spacing_px.max(0.1)) as usize + 1).clamp(2, pts.len());
        let mut n = 0;
        for i in 0..count {
            let t = t0 + (t1 - t0) * (i as f32 + 0.5) / count as f32;
            if let Some((nrm, _)) = at(t) {
                pts[n] = nrm;
                n += 1;
            }
        }
        if n < 2 {
            if is_end {
                continue;
            }
            return None;
        }
        // Move each point across the edge by the noise (in pixels).
        let dir = (pts[n - 1] - pts[0]).normalized()?;
        let normal = dir.perp();
        for p in pts[..n].iter_mut() {
            *p += normal * (noise() / f);
        }
        stats[e as usize] = EdgeStats::from_points(pts[..n].iter().copied());
    }
    Some(LineObservation { top: stats[0]?, bottom: stats[1]?, start_end: stats[2], finish_end: stats[3] })
}

/// An analytic observation cut to what the detector would report (the detector's own limits, see
/// [`crate::detect`]): each long edge at least `min_long_edge_points` pixels long (the detector measures one
/// point per image column) and at least `min_inlier_fraction` of the longer one (columns where one edge is
/// clipped count against the band), the band at least `min_length_px` long, and an end edge with fewer than
/// `min_end_points` pixels dropped. `None` when the detector would find no target.
pub fn within_detector_limits(
    obs: LineObservation,
    focal_px: f32,
    params: &crate::detect::DetectorParams,
) -> Option<LineObservation> {
    // Points of an edge are spaced evenly, so its length is sqrt(12) times their spread along it.
    let length_px = |s: &EdgeStats| 3.464_101_6 * s.spread * focal_px;
    let (top, bottom) = (length_px(&obs.top), length_px(&obs.bottom));
    let (short, long) = (top.min(bottom), top.max(bottom));
    if short < params.min_long_edge_points as f32
        || short < params.min_inlier_fraction * long
        || long < params.min_length_px
    {
        return None;
    }
    let end = |s: Option<EdgeStats>| s.filter(|s| length_px(s) >= params.min_end_points as f32);
    Some(LineObservation { start_end: end(obs.start_end), finish_end: end(obs.finish_end), ..obs })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_of_points_on_a_line() {
        // Points on y = 0.1 x + 0.2, with alternating offsets of +-1e-3 across the line.
        let pts: Vec<Vec2> = (0..101)
            .map(|i| {
                let x = -0.5 + i as f32 * 0.01;
                let off = if i % 2 == 0 { 1e-3 } else { -1e-3 };
                Vec2::new(x, 0.1 * x + 0.2) + Vec2::new(-0.1, 1.0).normalized().unwrap() * off
            })
            .collect();
        let s = EdgeStats::from_points(pts.iter().copied()).unwrap();
        assert_eq!(s.count, 101);
        let l = s.line();
        // Passes through (0, 0.2) with slope 0.1.
        assert!((l.y * 0.2 + l.z).abs() < 2e-5);
        assert!((-l.x / l.y - 0.1).abs() < 1e-5);
        assert!((s.rms - 1e-3).abs() < 2e-5);
        // 101 points 0.01 apart in x along slope 0.1: RMS spread = 0.01 sqrt(1.01) sqrt(50 * 51 / 3).
        let expected = 0.01 * 1.01f32.sqrt() * (50.0f32 * 51.0 / 3.0).sqrt();
        assert!((s.spread - expected).abs() < 1e-4, "{} {expected}", s.spread);
        assert!(EdgeStats::from_points([Vec2::ZERO].into_iter()).is_none());
    }

    #[test]
    fn the_analytic_camera_keeps_to_the_detectors_limits() {
        use geometry::frames::{Attitude, BODY_FROM_FORWARD_CAMERA};
        let cam = CameraModel::PAPER_FORWARD;
        let target = crate::target::LineTarget::PAPER;
        let params = crate::detect::DetectorParams::default();
        let r_cw = |yaw: f32| {
            Attitude::new(0.0, 0.0, yaw).world_from_body().mul_mat(&BODY_FROM_FORWARD_CAMERA).transpose()
        };
        // The paper's hover point: both edges long, both ends in view, nothing changed.
        let full =
            project_observation(&cam, &target, &r_cw(0.0), Vec3::new(1.15, 1.3, 0.8), 8.0, 2.0, || 0.0)
                .unwrap();
        assert!(full.start_end.is_some() && full.finish_end.is_some());
        assert_eq!(within_detector_limits(full, cam.focal_px(), &params), Some(full));
        // Turned so far that the band leaves the image but for its end: the projection still reports a few
        // points of each edge, the detector would not.
        let mut seen_cut = false;
        for k in 0..250 {
            let yaw = 0.6 + 0.004 * k as f32;
            let Some(o) =
                project_observation(&cam, &target, &r_cw(yaw), Vec3::new(1.15, 1.3, 0.8), 8.0, 2.0, || 0.0)
            else {
                continue;
            };
            let px = |s: &EdgeStats| 3.464 * s.spread * cam.focal_px();
            let kept = within_detector_limits(o, cam.focal_px(), &params);
            assert_eq!(
                kept.is_none(),
                px(&o.top).min(px(&o.bottom)) < 20.0 || px(&o.top).max(px(&o.bottom)) < 40.0,
                "yaw {yaw}"
            );
            seen_cut |= kept.is_none();
        }
        assert!(seen_cut, "no pose near the image edge was tried");
        let mut clipped = full;
        clipped.top.spread = 5.0 / (3.464 * cam.focal_px());
        assert!(within_detector_limits(clipped, cam.focal_px(), &params).is_none(), "a 5 px top edge");
        let mut short_end = full;
        if let Some(e) = short_end.start_end.as_mut() {
            e.spread = 3.0 / (3.464 * cam.focal_px());
        }
        let kept = within_detector_limits(short_end, cam.focal_px(), &params).unwrap();
        assert!(kept.start_end.is_none() && kept.finish_end.is_some(), "a 3 px end edge is dropped");
    }
}
