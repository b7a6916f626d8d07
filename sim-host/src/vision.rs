//! The ground station's vision (the `ground-station` crate's) on this crate's images, with JSON reports and
//! overlays for the command line.
use crate::imageio::RgbImage;
use crate::scenario::Scenario;
use geometry::{Vec2, frames::Attitude};
use serde_json::{Value, json};
use vision_core::{AttitudeSource, DetectorParams, LineObservation, NoTargetReason};

pub use ground_station::vision::{FrameResult, NoPose, PoseMethod};

/// Frames in which the detector found no line, counted by its reason (the station's counter, with the JSON a
/// summary holds).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NoTargetCounts(pub ground_station::vision::NoTargetCounts);

impl NoTargetCounts {
    /// Counts a detection's outcome and passes its observation on (`None` when it found no line).
    pub fn record(&mut self, detection: Result<LineObservation, NoTargetReason>) -> Option<LineObservation> {
        self.0.record(detection)
    }

    /// Frames refused for `reason`.
    pub fn get(&self, reason: NoTargetReason) -> u64 {
        self.0.get(reason)
    }

    /// Frames refused for any reason.
    pub fn total(&self) -> u64 {
        self.0.total()
    }

    /// Every reason's count by its code (zeros included, so the keys do not depend on the flight).
    pub fn to_json(&self) -> Value {
        let map: serde_json::Map<String, Value> =
            NoTargetReason::ALL.iter().map(|r| (r.code().to_string(), json!(self.get(*r)))).collect();
        Value::Object(map)
    }

    /// The reasons that occurred, largest first: `no_red_pixels 120, line_clipped 4` (empty when none).
    pub fn describe(&self) -> String {
        self.0.describe()
    }
}

/// The ground station's line vision for a scenario's forward camera and line
/// ([`ground_station::vision::LineVision`], on this crate's images).
pub struct GroundVision {
    scenario: Scenario,
    inner: ground_station::vision::LineVision,
}

impl GroundVision {
    /// Vision for a scenario's camera and line.
    pub fn new(scenario: &Scenario) -> Self {
        let inner = ground_station::vision::LineVision::new(
            scenario.forward_camera_model(),
            scenario.line_target(),
            scenario.forward_camera_mount(),
        );
        Self { scenario: scenario.clone(), inner }
    }

    /// The detector's tuning.
    pub fn detector_params(&self) -> &DetectorParams {
        self.inner.detector_params()
    }

    /// Detects the line.
    pub fn detect(&mut self, img: &RgbImage) -> Result<LineObservation, NoTargetReason> {
        self.inner.detect(&img.view())
    }

    /// Detects the line and solves the pose.
    pub fn pose(
        &mut self,
        img: &RgbImage,
        source: AttitudeSource,
        method: PoseMethod,
    ) -> Result<FrameResult, NoPose> {
        self.inner.pose(&img.view(), source, method)
    }

    /// [`Self::pose`] for a rolling-shutter camera turning during its readout.
    pub fn pose_timed(
        &mut self,
        img: &RgbImage,
        source: AttitudeSource,
        method: PoseMethod,
        timing: Option<&vision_core::RowTiming>,
    ) -> Result<FrameResult, NoPose> {
        self.inner.pose_timed(&img.view(), source, method, timing)
    }

    /// Detects the line in the frame of a rolling-shutter camera turning during its readout.
    pub fn detect_timed(
        &mut self,
        img: &RgbImage,
        timing: Option<&vision_core::RowTiming>,
    ) -> Result<LineObservation, NoTargetReason> {
        self.inner.detect_timed(&img.view(), timing)
    }

    /// The scenario.
    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }
}

fn r6(v: f32) -> Value {
    // Six decimals: sub-micrometre, and stable text for tests and diffs.
    json!((v as f64 * 1e6).round() / 1e6)
}

/// The JSON report of `sim-host vision pose` for a successful frame.
pub fn pose_json(r: &FrameResult, scenario: &Scenario, source: AttitudeSource) -> Value {
    let p = &r.pose;
    let cam = scenario.forward_camera_model();
    let corners: Vec<Value> = r
        .observation
        .corners_px(&cam)
        .iter()
        .map(|c| c.map_or(Value::Null, |c| json!([r6(c.x), r6(c.y)])))
        .collect();
    let rot: Vec<Value> =
        p.camera_from_world.m.iter().map(|row| json!([r6(row[0]), r6(row[1]), r6(row[2])])).collect();
    let a: Attitude = p.attitude;
    let finite_or_null = |v: f32| if v.is_finite() { r6(v) } else { Value::Null };
    json!({
        "status": "ok",
        "position_m": {
            "x": if p.x_observed { r6(p.camera_position_m.x) } else { Value::Null },
            "y": r6(p.camera_position_m.y),
            "z": r6(p.camera_position_m.z),
        },
        "rotation": rot,
        "corners_px": corners,
        "real_corners": p.real_corners,
        "reprojection_rms_px": r6(p.reprojection_rms_px),
        "ambiguity_ratio": r6(p.ambiguity_ratio),
        "position_std_m": {
            "x": if p.x_observed { finite_or_null(p.position_std_m.x) } else { Value::Null },
            "y": finite_or_null(p.position_std_m.y),
            "z": finite_or_null(p.position_std_m.z),
        },
        "attitude_deg": {
            "roll": r6(geometry::to_deg(a.roll)),
            "pitch": r6(geometry::to_deg(a.pitch)),
            "yaw": r6(geometry::to_deg(a.yaw)),
        },
        "solver": match source { AttitudeSource::ImageOnly => "image_only", AttitudeSource::Imu { .. } => "imu_aided" },
        "conventions": {
            "position_m": "camera centre, world frame (x along the wall, y from the wall to the vehicle, z up)",
            "rotation": "R_CW, world to camera (columns: world axes in OpenCV camera coordinates)",
            "corners_px": "A (x_start, bottom), B (x_start, top), C (x_end, top), D (x_end, bottom); null when not in view",
        },
    })
}

/// The JSON report for a frame without a pose.
pub fn no_target_json(why: NoPose) -> Value {
    json!({"status": "no_target", "reason": why.code(), "detail": why.describe()})
}

/// Draws the measured edges and corners over the frame.
pub fn draw_overlay(img: &mut RgbImage, obs: &LineObservation, scenario: &Scenario) {
    let cam = scenario.forward_camera_model();
    let edges = [
        (Some(obs.top), [0, 255, 0]),
        (Some(obs.bottom), [0, 255, 0]),
        (obs.start_end, [0, 200, 255]),
        (obs.finish_end, [0, 200, 255]),
    ];
    for (e, colour) in edges {
        let Some(e) = e else { continue };
        let (a, b) = e.extent();
        let (pa, pb) = (cam.normalized_to_pixel(a), cam.normalized_to_pixel(b));
        let n = ((pb - pa).norm() as usize).max(1);
        for i in 0..=n {
            let p = pa + (pb - pa) * (i as f32 / n as f32);
            img.put(p.x.round() as i64, p.y.round() as i64, colour);
        }
    }
    for c in obs.corners_px(&cam).into_iter().flatten() {
        draw_cross(img, c, [255, 255, 0]);
    }
}

fn draw_cross(img: &mut RgbImage, c: Vec2, colour: [u8; 3]) {
    let (x, y) = (c.x.round() as i64, c.y.round() as i64);
    for d in -6..=6 {
        img.put(x + d, y, colour);
        img.put(x, y + d, colour);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_target_counts_keep_each_reason_apart() {
        let mut c = NoTargetCounts::default();
        assert_eq!(c.describe(), "");
        assert_eq!(c.record(Err(NoTargetReason::LineClipped)), None);
        for _ in 0..3 {
            c.record(Err(NoTargetReason::NoRedPixels));
        }
        assert_eq!(c.get(NoTargetReason::NoRedPixels), 3);
        assert_eq!(c.get(NoTargetReason::LineClipped), 1);
        assert_eq!(c.get(NoTargetReason::TooMuchRed), 0);
        assert_eq!(c.total(), 4);
        assert_eq!(c.describe(), "no_red_pixels 3, line_clipped 1");
        let j = c.to_json();
        assert_eq!(j.as_object().unwrap().len(), NoTargetReason::ALL.len());
        assert_eq!(j["no_red_pixels"], 3);
        assert_eq!(j["line_clipped"], 1);
        assert_eq!(j["edges_not_straight"], 0);
    }
}
