//! The ground station's side of the downward camera: optical flow of each frame pair, from rendered images
//! (vision-core's pyramidal Lucas-Kanade) or, in the fast analytic mode, from exactly projected floor points
//! with tracking noise, both summarised by the same robust statistics.
use crate::imageio::GrayImage;
use crate::rng::SimRng;
use crate::scenario::Scenario;
use geometry::{Mat3, Vec2, Vec3};
use serde_json::{Value, json};
use vision_core::CameraModel;
use vision_core::flow::{self, FlowParams, FlowStats, NoFlowReason};

/// A camera pose in the world: rotation (world from camera) and centre.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CamPose {
    /// World from camera.
    pub r_wc: Mat3,
    /// Centre (m).
    pub center: Vec3,
}

/// The flow of frame pairs, frame after frame ([`ground_station::vision::FlowTracker`] on this crate's
/// images).
pub struct GroundFlow(ground_station::vision::FlowTracker);

impl GroundFlow {
    /// For the scenario's downward camera, with the default flow parameters.
    pub fn new(s: &Scenario) -> Self {
        let camera = s.down_camera_model();
        Self::with_params(camera, FlowParams::for_image(camera.width, camera.height))
    }

    /// For a camera and parameters.
    pub fn with_params(camera: CameraModel, params: FlowParams) -> Self {
        Self(ground_station::vision::FlowTracker::new(camera, params))
    }

    /// The camera.
    pub fn camera(&self) -> &CameraModel {
        self.0.camera()
    }

    /// The parameters.
    pub fn params(&self) -> &FlowParams {
        self.0.params()
    }

    /// Adds a frame; from the second one on, returns the flow from the previous frame, seeded with the
    /// predicted camera rotation over the interval (camera frame, rad).
    pub fn add(
        &mut self,
        img: &GrayImage,
        predicted_rotation_cam: Vec3,
    ) -> Option<Result<FlowStats, NoFlowReason>> {
        self.0.add(&img.view(), predicted_rotation_cam)
    }

    /// The flow between two frames (a fresh pair).
    pub fn between(
        &mut self,
        prev: &GrayImage,
        next: &GrayImage,
        predicted_rotation_cam: Vec3,
    ) -> Result<FlowStats, NoFlowReason> {
        self.0.between(&prev.view(), &next.view(), predicted_rotation_cam)
    }

    /// Where the floor repeats, when the last pair was refused as [`NoFlowReason::RepeatingTexture`].
    pub fn repetition(&self) -> Option<vision_core::flow::Repetition> {
        self.0.repetition()
    }

    /// The last pair's counts (selected, in view, tracked, inliers, the fit's residual), also when refused.
    pub fn last_counts(&self) -> vision_core::flow::PairCounts {
        self.0.last_counts()
    }

    /// The last pair's tracks (position px, displacement px, inlier), for display.
    pub fn last_tracks(&self) -> impl Iterator<Item = (geometry::Vec2, geometry::Vec2, bool)> + '_ {
        self.0.last_tracks()
    }
}

/// The analytic stand-in for the tracker: floor points on a grid of the earlier frame, projected exactly into
/// the later one, with Gaussian tracking noise (px); points whose view leaves the image are lost.
pub fn analytic_flow(
    camera: &CameraModel,
    params: &FlowParams,
    prev: &CamPose,
    next: &CamPose,
    noise_px: f64,
    rng: &mut SimRng,
    predicted_rotation_cam: Vec3,
) -> Result<FlowStats, NoFlowReason> {
    let (w, h) = (camera.width as f32, camera.height as f32);
    let [gx, gy] = params.grid.map(|g| g.max(1) as usize);
    let margin = params.window_half as f32 + 2.0;
    let mut tracks = Vec::with_capacity(gx * gy);
    let r_cw_next = next.r_wc.transpose();
    for j in 0..gy {
        for i in 0..gx {
            let u = margin
                + (i as f32 + 0.5 + 0.6 * (rng.uniform() as f32 - 0.5)) * (w - 2.0 * margin) / gx as f32;
            let v = margin
                + (j as f32 + 0.5 + 0.6 * (rng.uniform() as f32 - 0.5)) * (h - 2.0 * margin) / gy as f32;
            let p = Vec2::new(u, v);
            let n = camera.pixel_to_normalized(p);
            let d = prev.r_wc.mul_vec(Vec3::new(n.x, n.y, 1.0));
            if d.z > -1e-3 {
                continue;
            }
            let t = -prev.center.z / d.z;
            let world = prev.center + d * t;
            let c = r_cw_next.mul_vec(world - next.center);
            if c.z <= 1e-3 {
                continue;
            }
            let q = camera.normalized_to_pixel(Vec2::new(c.x / c.z, c.y / c.z));
            let noise = Vec2::new((noise_px * rng.normal()) as f32, (noise_px * rng.normal()) as f32);
            let q = q + noise;
            if q.x < margin || q.y < margin || q.x > w - 1.0 - margin || q.y > h - 1.0 - margin {
                continue;
            }
            tracks.push((p, q - p));
        }
    }
    flow::stats_from_tracks(&tracks, gx * gy, camera, params, predicted_rotation_cam)
}

/// The JSON of one flow for the CLI: `{"status": "ok", "flow_px", "tracked", "selected", "quality",
/// "residual_px", ["velocity_m_s", "velocity_frame"]}`. `fx_px` is the camera's focal length in pixels: the
/// fit's residual is computed in normalised image units and reported in pixels.
pub fn flow_json(s: &FlowStats, fx_px: f32, velocity_body: Option<[f32; 2]>) -> Value {
    let mut v = json!({
        "status": "ok",
        "flow_px": [s.median_flow_px.x, s.median_flow_px.y],
        "tracked": s.inliers,
        "selected": s.selected,
        "quality": s.quality,
        "residual_px": s.residual_rms * fx_px,
    });
    if let Some(vel) = velocity_body {
        v["velocity_m_s"] = json!(vel);
        v["velocity_frame"] = json!("body (x forward, y left)");
    }
    v
}

/// The JSON of a frame pair without flow: the reason, and the numbers behind it (`counts` of the pair) against
/// the limits that refused it (`params`, the flow's); for a repeating floor, where it repeats
/// (`repeats_every_px`, the offset in pixels of the earlier frame) and how well (`repetition_ratio`: the match
/// there over the typical one, 0 for a perfect repetition).
pub fn no_flow_json(
    why: NoFlowReason,
    repetition: Option<vision_core::flow::Repetition>,
    counts: &vision_core::flow::PairCounts,
    params: &FlowParams,
) -> Value {
    let residual = counts.residual_px.is_finite().then_some(counts.residual_px);
    let mut v = json!({
        "status": "no_flow",
        "reason": why.code(),
        "message": why.describe(),
        "selected": counts.selected,
        "in_view": counts.in_view,
        "tracked": counts.tracked,
        "inliers": counts.inliers,
        "quality": counts.quality(),
        "residual_px": residual,
        "limits": {
            "min_tracks": params.min_tracks,
            "min_quality": params.min_quality,
            "max_residual_px": params.max_residual_px,
        },
    });
    if let Some(r) = repetition {
        v["repeats_every_px"] = json!([r.offset_px.x, r.offset_px.y]);
        v["repetition_ratio"] = json!(r.ratio);
    }
    v
}
