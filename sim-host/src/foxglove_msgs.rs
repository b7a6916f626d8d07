//! The Foxglove well-known messages (the `foxglove` crate's typed, protobuf-encoded schemas) built from the
//! flight's records: poses, body frames, the scene, images and their annotations. One builder for the MCAP
//! export (`crate::export`) and the live view (`crate::live`), so that a file and a live flight show the same
//! thing on the same topics (docs/log-format.md, "Export"; docs/live-view.md).
use crate::flightlog::{CameraFrame, CameraId, FrameEncoding, LogRecord, StationEvent};
use crate::scenario::Scenario;
use foxglove::messages::{
    Color, CompressedImage, CubePrimitive, CylinderPrimitive, FrameTransform, FrameTransforms,
    ImageAnnotations, Point2, PointsAnnotation, Pose, PoseInFrame, Quaternion, RawImage, SceneEntity,
    SceneUpdate, Timestamp, Vector3, points_annotation,
};
use geometry::{Quat, Vec2, Vec3};
use vision_core::observation::LineObservation;
use vision_core::target::Corner;

/// Time between two scene updates (us, on the records' clock).
pub const SCENE_EVERY_US: u64 = 100_000;

/// The estimate's body frame.
pub const ESTIMATE_FRAME: &str = "base_link";
/// The truth's body frame (simulation only).
pub const TRUTH_FRAME: &str = "base_link_truth";

pub(crate) fn stamp(t_us: u64) -> Option<Timestamp> {
    Some(Timestamp::new((t_us / 1_000_000) as u32, ((t_us % 1_000_000) * 1000) as u32))
}

pub(crate) fn color(r: f64, g: f64, b: f64, a: f64) -> Option<Color> {
    Some(Color { r, g, b, a })
}

pub(crate) fn v3(v: Vec3) -> Option<Vector3> {
    Some(Vector3 { x: v.x as f64, y: v.y as f64, z: v.z as f64 })
}

pub(crate) fn quat(q: Quat) -> Option<Quaternion> {
    Some(Quaternion { x: q.x as f64, y: q.y as f64, z: q.z as f64, w: q.w as f64 })
}

pub(crate) fn pose(p: Vec3, q: Quat) -> Option<Pose> {
    Some(Pose { position: v3(p), orientation: quat(q) })
}

pub(crate) fn px(p: Vec2) -> Point2 {
    Point2 { x: p.x as f64, y: p.y as f64 }
}

pub(crate) fn points(
    kind: points_annotation::Type,
    pts: Vec<Point2>,
    rgba: [f64; 4],
    thickness: f64,
) -> PointsAnnotation {
    PointsAnnotation {
        timestamp: None,
        r#type: kind as i32,
        points: pts,
        outline_color: color(rgba[0], rgba[1], rgba[2], rgba[3]),
        thickness,
        ..Default::default()
    }
}

/// A pose in `frame` as `foxglove.PoseInFrame`.
pub(crate) fn pose_in_frame(t_us: u64, frame: &str, p: Vec3, q: Quat) -> PoseInFrame {
    PoseInFrame { timestamp: stamp(t_us), frame_id: frame.into(), pose: pose(p, q) }
}

/// A logged frame as a Foxglove image: PNG as `foxglove.CompressedImage`, raw as `foxglove.RawImage`.
pub(crate) enum Image {
    /// PNG (or JPEG) bytes.
    Compressed(CompressedImage),
    /// Pixels, `rgb8` or `mono8`.
    Raw(RawImage),
}

/// The image frame's name of a camera.
pub(crate) fn camera_frame_id(c: CameraId) -> &'static str {
    match c {
        CameraId::Forward => "camera_forward",
        CameraId::Downward => "camera_down",
    }
}

/// A logged frame as the Foxglove image message its encoding asks for.
pub(crate) fn image_message(f: &CameraFrame) -> Image {
    let frame_id = camera_frame_id(f.camera).to_string();
    match f.encoding {
        FrameEncoding::Png => Image::Compressed(CompressedImage {
            timestamp: stamp(f.capture_time_us),
            frame_id,
            data: f.data.clone().into(),
            format: "png".into(),
        }),
        FrameEncoding::Raw => Image::Raw(RawImage {
            timestamp: stamp(f.capture_time_us),
            frame_id,
            width: f.width as u32,
            height: f.height as u32,
            encoding: if f.channels == 3 { "rgb8" } else { "mono8" }.into(),
            step: f.width as u32 * f.channels as u32,
            data: f.data.clone().into(),
        }),
    }
}

/// Where the vehicle is along a log, as the records say: the latest estimate (a step's report, or a station's
/// telemetry at the station's clock) and truth, the last step's time, and when the next scene is due.
#[derive(Clone, Debug, Default)]
pub(crate) struct Bodies {
    /// The last step's time (us): the time of a step's outputs.
    pub(crate) step_us: u64,
    /// The latest estimate (world position, attitude).
    pub(crate) estimate: Option<(Vec3, Quat)>,
    /// The latest truth.
    pub(crate) truth: Option<(Vec3, Quat)>,
    next_scene_us: u64,
}

impl Bodies {
    /// Takes a record; the time at which the estimate changed, when it did.
    pub(crate) fn update(&mut self, r: &LogRecord) -> Option<u64> {
        match r {
            LogRecord::Step(s) => {
                self.step_us = s.time_us;
                None
            }
            LogRecord::Report(rep) => {
                let e = &rep.control.estimate;
                self.estimate = Some((e.position_m, e.q));
                Some(self.step_us)
            }
            LogRecord::Station(StationEvent::Received { station_time_us, message }) => {
                let tm = message.telemetry()?;
                self.estimate = Some((tm.estimate.position_m, tm.estimate.q));
                Some(*station_time_us)
            }
            LogRecord::Truth { position_m, attitude_rad, .. } => {
                let att = geometry::frames::Attitude {
                    roll: attitude_rad[0],
                    pitch: attitude_rad[1],
                    yaw: attitude_rad[2],
                };
                let p = Vec3::new(position_m[0], position_m[1], position_m[2]);
                self.truth = Some((p, Quat::from_mat3(&att.world_from_body())));
                None
            }
            _ => None,
        }
    }

    /// The body frames known at `t_us` (the estimate's, the truth's), or None before the first.
    pub(crate) fn transforms(&self, t_us: u64) -> Option<FrameTransforms> {
        let tf = |child: &str, (p, q): (Vec3, Quat)| FrameTransform {
            timestamp: stamp(t_us),
            parent_frame_id: "world".into(),
            child_frame_id: child.into(),
            translation: v3(p),
            rotation: quat(q),
        };
        let transforms: Vec<FrameTransform> = [(ESTIMATE_FRAME, self.estimate), (TRUTH_FRAME, self.truth)]
            .into_iter()
            .filter_map(|(child, b)| b.map(|b| tf(child, b)))
            .collect();
        (!transforms.is_empty()).then_some(FrameTransforms { transforms })
    }

    /// Whether a scene is due at `t_us` (every [`SCENE_EVERY_US`]); when it is, the next one is scheduled.
    pub(crate) fn scene_due(&mut self, t_us: u64) -> bool {
        if t_us >= self.next_scene_us {
            self.next_scene_us = t_us + SCENE_EVERY_US;
            true
        } else {
            false
        }
    }
}

/// Where the forward camera sees the line's corners from a body pose (world position, attitude), or None
/// when a corner is behind it.
pub fn reprojected_corners(s: &Scenario, (p, q): (Vec3, Quat)) -> Option<[Vec2; 4]> {
    let cam = s.forward_camera_model();
    let mount = s.forward_camera_mount();
    let r_wb = q.to_mat3();
    let target = s.line_target();
    let mut out = [Vec2::ZERO; 4];
    for (o, c) in out.iter_mut().zip(Corner::ALL) {
        let body = r_wb.transpose().mul_vec(target.corner(c) - p) - mount.offset_body_m;
        let pc = mount.body_from_camera.transpose().mul_vec(body);
        if pc.z < 0.05 {
            return None;
        }
        *o = cam.normalized_to_pixel(Vec2::new(pc.x / pc.z, pc.y / pc.z));
    }
    Some(out)
}

/// The forward image's annotations: the detected edges (green, the ends cyan), the corners (yellow) and the
/// line reprojected from the estimate (magenta).
pub(crate) fn forward_annotations(
    s: &Scenario,
    t_us: u64,
    detection: Option<&LineObservation>,
    estimate: Option<(Vec3, Quat)>,
) -> ImageAnnotations {
    let cam = s.forward_camera_model();
    let mut out = ImageAnnotations { timestamp: stamp(t_us), ..Default::default() };
    if let Some(obs) = detection {
        for (edge, rgba) in [
            (Some(obs.top), [0.0, 1.0, 0.0, 1.0]),
            (Some(obs.bottom), [0.0, 1.0, 0.0, 1.0]),
            (obs.start_end, [0.0, 0.8, 1.0, 1.0]),
            (obs.finish_end, [0.0, 0.8, 1.0, 1.0]),
        ] {
            let Some(e) = edge else { continue };
            let (a, b) = e.extent();
            let pts = vec![px(cam.normalized_to_pixel(a)), px(cam.normalized_to_pixel(b))];
            out.points.push(points(points_annotation::Type::LineList, pts, rgba, 2.0));
        }
        let corners: Vec<Point2> = obs.corners_px(&cam).into_iter().flatten().map(px).collect();
        if !corners.is_empty() {
            out.points.push(points(points_annotation::Type::Points, corners, [1.0, 1.0, 0.0, 1.0], 8.0));
        }
    }
    if let Some(c) = estimate.and_then(|e| reprojected_corners(s, e)) {
        out.points.push(points(
            points_annotation::Type::LineLoop,
            c.iter().map(|p| px(*p)).collect(),
            [1.0, 0.0, 1.0, 0.9],
            1.5,
        ));
    }
    out
}

/// The downward image's annotations: each track's start (green when the velocity used it, red when not)
/// and its flow drawn five times longer.
pub fn down_annotations(t_us: u64, tracks: &[(Vec2, Vec2, bool)]) -> ImageAnnotations {
    const SCALE: f32 = 5.0;
    let mut out = ImageAnnotations { timestamp: stamp(t_us), ..Default::default() };
    for (inlier, rgba) in [(true, [0.0, 1.0, 0.0, 1.0]), (false, [1.0, 0.2, 0.2, 1.0])] {
        let sel: Vec<_> = tracks.iter().filter(|t| t.2 == inlier).collect();
        if sel.is_empty() {
            continue;
        }
        out.points.push(points(
            points_annotation::Type::Points,
            sel.iter().map(|t| px(t.0)).collect(),
            rgba,
            4.0,
        ));
        let lines = sel.iter().flat_map(|t| [px(t.0), px(t.0 + t.1 * SCALE)]).collect();
        out.points.push(points(points_annotation::Type::LineList, lines, rgba, 1.0));
    }
    out
}

/// The wall, the line, and the vehicle as the estimate and (in simulation) the truth place it.
pub(crate) fn scene(s: &Scenario, t_us: u64, with_truth: bool) -> SceneUpdate {
    let target = s.line_target();
    let (x0, x1) = (target.x_start_m.min(0.0) - 1.0, target.x_end_m.max(0.0) + 1.0);
    let height = (target.z_top_m + 1.0).max(2.0);
    let entity =
        |id: &str, frame: &str, cubes: Vec<CubePrimitive>, cylinders: Vec<CylinderPrimitive>| SceneEntity {
            timestamp: stamp(t_us),
            frame_id: frame.into(),
            id: id.into(),
            frame_locked: frame != "world",
            cubes,
            cylinders,
            ..Default::default()
        };
    let cube = |centre: Vec3, size: Vec3, rgba: [f64; 4]| CubePrimitive {
        pose: pose(centre, Quat::IDENTITY),
        size: v3(size),
        color: color(rgba[0], rgba[1], rgba[2], rgba[3]),
    };
    // The wall is the plane y = 0 of the world frame (docs/frames.md), seen from y > 0.
    let wall = cube(
        Vec3::new(0.5 * (x0 + x1), -0.01, 0.5 * height),
        Vec3::new(x1 - x0, 0.02, height),
        [0.85, 0.85, 0.8, 1.0],
    );
    let line = cube(
        Vec3::new(
            0.5 * (target.x_start_m + target.x_end_m),
            0.001,
            0.5 * (target.z_bottom_m + target.z_top_m),
        ),
        Vec3::new(target.length_m(), 0.004, target.height_m()),
        [0.9, 0.05, 0.05, 1.0],
    );
    let vehicle = |alpha: f64| {
        let arm = s.vehicle.arm_length_m;
        let rgba = [0.2, 0.3, 0.9, alpha];
        let cubes = vec![
            cube(Vec3::ZERO, Vec3::new(0.12, 0.12, 0.05), rgba),
            cube(Vec3::ZERO, Vec3::new(2.0 * arm, 0.02, 0.02), rgba),
            cube(Vec3::ZERO, Vec3::new(0.02, 2.0 * arm, 0.02), rgba),
        ];
        let rotors = [
            Vec3::new(arm, 0.0, 0.03),
            Vec3::new(-arm, 0.0, 0.03),
            Vec3::new(0.0, arm, 0.03),
            Vec3::new(0.0, -arm, 0.03),
        ]
        .into_iter()
        .map(|c| CylinderPrimitive {
            pose: pose(c, Quat::IDENTITY),
            size: v3(Vec3::new(0.2, 0.2, 0.01)),
            bottom_scale: 1.0,
            top_scale: 1.0,
            color: color(0.1, 0.1, 0.1, alpha * 0.6),
        })
        .collect();
        (cubes, rotors)
    };
    let mut entities = vec![entity("wall", "world", vec![wall, line], vec![])];
    let (cubes, rotors) = vehicle(1.0);
    entities.push(entity("vehicle_estimate", ESTIMATE_FRAME, cubes, rotors));
    if with_truth {
        let (cubes, rotors) = vehicle(0.35);
        entities.push(entity("vehicle_truth", TRUTH_FRAME, cubes, rotors));
    }
    SceneUpdate { deletions: vec![], entities }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_line_reprojects_where_the_renderer_draws_it() {
        // Level, 1.3 m from the wall, facing it from the line's middle at its height: the line's image is
        // centred, its long edges horizontal and symmetric about the principal point's column.
        let s = Scenario::paper();
        let t = s.line_target();
        let mount = s.forward_camera_mount();
        let yaw = s.flight_params().trajectory.yaw_d_rad;
        let q = Quat::from_mat3(&geometry::frames::Attitude { roll: 0.0, pitch: 0.0, yaw }.world_from_body());
        let cam_height = 0.5 * (t.z_bottom_m + t.z_top_m);
        let p = Vec3::new(0.5 * (t.x_start_m + t.x_end_m), 1.3, cam_height)
            - q.to_mat3().mul_vec(mount.offset_body_m);
        let c = reprojected_corners(&s, (p, q)).expect("in front of the camera");
        let cam = s.forward_camera_model();
        let mid = (c[0] + c[1] + c[2] + c[3]) * 0.25;
        assert!((mid.x - cam.cx).abs() < 1.0 && (mid.y - cam.cy).abs() < 1.0, "{c:?}");
        // Corner A (start, bottom) and D (finish, bottom) on one row; B and C above them.
        assert!((c[0].y - c[3].y).abs() < 0.5 && (c[1].y - c[2].y).abs() < 0.5, "{c:?}");
        assert!(c[1].y < c[0].y, "{c:?}");
        // The image's size of the line: 2.30 m at 1.3 m with the scenario's focal length.
        let width = (c[3].x - c[0].x).abs();
        let expected = cam.fx * t.length_m() / 1.3;
        assert!((width - expected).abs() < 0.02 * expected, "{width} vs {expected}");
        // Behind the camera: none.
        let behind = Vec3::new(p.x, -1.0, p.z);
        assert!(reprojected_corners(&s, (behind, q)).is_none());
    }

    #[test]
    fn flow_annotations_split_inliers_from_outliers() {
        let tracks = [
            (Vec2::new(10.0, 20.0), Vec2::new(1.0, 0.0), true),
            (Vec2::new(30.0, 40.0), Vec2::new(0.0, 2.0), false),
            (Vec2::new(50.0, 60.0), Vec2::new(-1.0, 0.0), true),
        ];
        let a = down_annotations(7_000_000, &tracks);
        assert_eq!(a.points.len(), 4);
        assert_eq!(a.points[0].points.len(), 2);
        assert_eq!(a.points[1].points.len(), 4);
        assert_eq!(a.points[1].points[1], Point2 { x: 15.0, y: 20.0 });
        assert_eq!(a.points[2].points, vec![Point2 { x: 30.0, y: 40.0 }]);
        assert_eq!(a.timestamp, stamp(7_000_000));
        assert!(down_annotations(0, &[]).points.is_empty());
    }
}
