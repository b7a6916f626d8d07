//! The station's vision: the forward camera's line (vision-core's detector and pose solver) and the downward
//! camera's optical flow, built from a camera's calibration and the line's geometry, not from a simulator's
//! scenario. The simulator's ground station runs this same code on rendered frames.
use vision_core::flow::{self, FlowParams, FlowStats, FlowWorkspace, NoFlowReason};
use vision_core::{
    AttitudeSource, CameraModel, CameraMount, DetectorParams, DetectorWorkspace, Gray8View, LineObservation,
    LineTarget, NoTargetReason, PoseError, PoseParams, PoseSolution, Rgb8View, solve_pose,
};

/// Which pose solver to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PoseMethod {
    /// Closed form, then reprojection-error refinement (default).
    Refined,
    /// Closed form only: vanishing points and least-squares translation.
    ClosedForm,
    /// The paper's method: vanishing points and depth from the line's apparent height.
    Paper,
}

impl PoseMethod {
    /// Solver parameters for this method.
    pub fn params(self) -> PoseParams {
        match self {
            PoseMethod::Refined => PoseParams::default(),
            PoseMethod::ClosedForm => {
                PoseParams { refine: false, check_ambiguity: false, ..PoseParams::default() }
            }
            PoseMethod::Paper => PoseParams {
                refine: false,
                check_ambiguity: false,
                translation: vision_core::TranslationMethod::PaperLineHeight,
                ..PoseParams::default()
            },
        }
    }
}

/// Why a frame gave no pose.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoPose {
    /// The detector found no line.
    Detection(NoTargetReason),
    /// The solver rejected the measurement.
    Solver(PoseError),
}

impl NoPose {
    /// Stable code.
    pub fn code(&self) -> &'static str {
        match self {
            NoPose::Detection(r) => r.code(),
            NoPose::Solver(e) => e.code(),
        }
    }
    /// Explanation.
    pub fn describe(&self) -> &'static str {
        match self {
            NoPose::Detection(r) => r.describe(),
            NoPose::Solver(e) => e.describe(),
        }
    }
}

/// A frame's vision result.
#[derive(Clone, Copy, Debug)]
pub struct FrameResult {
    /// The measurement.
    pub observation: LineObservation,
    /// The pose.
    pub pose: PoseSolution,
}

/// Frames in which the detector found no line, counted by its reason, so that a summary says why vision
/// was blind (no red at all, the line clipped by the image's edge, ...) rather than only how often.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NoTargetCounts {
    counts: [u64; NoTargetReason::ALL.len()],
}

impl NoTargetCounts {
    /// Counts a detection's outcome and passes its observation on (`None` when it found no line).
    pub fn record(&mut self, detection: Result<LineObservation, NoTargetReason>) -> Option<LineObservation> {
        match detection {
            Ok(observation) => Some(observation),
            Err(reason) => {
                self.counts[reason as usize] += 1;
                None
            }
        }
    }

    /// Frames refused for `reason`.
    pub fn get(&self, reason: NoTargetReason) -> u64 {
        self.counts[reason as usize]
    }

    /// Frames refused for any reason.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// The reasons that occurred, largest first: `no_red_pixels 120, line_clipped 4` (empty when none).
    pub fn describe(&self) -> String {
        let mut seen: Vec<(NoTargetReason, u64)> =
            NoTargetReason::ALL.iter().map(|r| (*r, self.get(*r))).filter(|(_, n)| *n > 0).collect();
        seen.sort_by_key(|(r, n)| (std::cmp::Reverse(*n), *r as usize));
        seen.iter().map(|(r, n)| format!("{} {n}", r.code())).collect::<Vec<_>>().join(", ")
    }
}

/// The forward camera's line: detection, and pose when asked.
pub struct LineVision {
    camera: CameraModel,
    target: LineTarget,
    mount: CameraMount,
    detector: DetectorParams,
    workspace: Box<DetectorWorkspace>,
}

impl LineVision {
    /// For a calibrated camera (intrinsics and distortion), the line it looks at, and the camera's mount on
    /// the vehicle (for the vehicle's pose).
    pub fn new(camera: CameraModel, target: LineTarget, mount: CameraMount) -> Self {
        Self {
            camera,
            target,
            mount,
            detector: DetectorParams::default(),
            workspace: Box::new(DetectorWorkspace::new()),
        }
    }

    /// The camera.
    pub fn camera(&self) -> &CameraModel {
        &self.camera
    }

    /// The camera's tone curve (from its calibration; sRGB unless set), which the detector undoes before it
    /// measures edges.
    pub fn with_tone_curve(mut self, curve: vision_core::ToneCurve) -> Self {
        self.detector.tone_curve = curve;
        self
    }

    /// The detector's tuning.
    pub fn detector_params(&self) -> &DetectorParams {
        &self.detector
    }

    /// Detects the line.
    pub fn detect(&mut self, img: &Rgb8View<'_>) -> Result<LineObservation, NoTargetReason> {
        self.detect_timed(img, None)
    }

    /// Detects the line in the frame of a rolling-shutter camera turning during its readout
    /// ([`vision_core::detect_line_timed`]).
    pub fn detect_timed(
        &mut self,
        img: &Rgb8View<'_>,
        timing: Option<&vision_core::RowTiming>,
    ) -> Result<LineObservation, NoTargetReason> {
        vision_core::detect_line_timed(img, &self.camera, &self.detector, &mut self.workspace, timing)
    }

    /// Detects the line and solves the pose.
    pub fn pose(
        &mut self,
        img: &Rgb8View<'_>,
        source: AttitudeSource,
        method: PoseMethod,
    ) -> Result<FrameResult, NoPose> {
        self.pose_timed(img, source, method, None)
    }

    /// [`Self::pose`] for a rolling-shutter camera turning during its readout.
    pub fn pose_timed(
        &mut self,
        img: &Rgb8View<'_>,
        source: AttitudeSource,
        method: PoseMethod,
        timing: Option<&vision_core::RowTiming>,
    ) -> Result<FrameResult, NoPose> {
        let observation = self.detect_timed(img, timing).map_err(NoPose::Detection)?;
        let pose =
            solve_pose(&observation, &self.camera, &self.target, &self.mount, source, &method.params())
                .map_err(NoPose::Solver)?;
        Ok(FrameResult { observation, pose })
    }
}

/// The downward camera's optical flow, frame after frame.
pub struct FlowTracker {
    camera: CameraModel,
    params: FlowParams,
    ws: Box<FlowWorkspace>,
    has_prev: bool,
}

impl FlowTracker {
    /// For a camera and flow parameters.
    pub fn new(camera: CameraModel, params: FlowParams) -> Self {
        Self { camera, params, ws: Box::new(FlowWorkspace::new()), has_prev: false }
    }

    /// The camera.
    pub fn camera(&self) -> &CameraModel {
        &self.camera
    }

    /// The parameters.
    pub fn params(&self) -> &FlowParams {
        &self.params
    }

    /// Adds a frame; from the second one on, returns the flow from the previous frame, seeded with the
    /// predicted camera rotation over the interval (camera frame, rad).
    pub fn add(
        &mut self,
        img: &Gray8View<'_>,
        predicted_rotation_cam: geometry::Vec3,
    ) -> Option<Result<FlowStats, NoFlowReason>> {
        let r = flow::add_frame(img, &self.camera, &self.params, predicted_rotation_cam, &mut self.ws);
        let first = !self.has_prev;
        self.has_prev = true;
        match r {
            Ok(None) => None,
            Ok(Some(s)) => Some(Ok(s)),
            Err(e) if first => {
                // A first frame of the wrong size: the next one starts again.
                self.ws.reset();
                self.has_prev = false;
                Some(Err(e))
            }
            Err(e) => Some(Err(e)),
        }
    }

    /// The flow between two frames (a fresh pair).
    pub fn between(
        &mut self,
        prev: &Gray8View<'_>,
        next: &Gray8View<'_>,
        predicted_rotation_cam: geometry::Vec3,
    ) -> Result<FlowStats, NoFlowReason> {
        flow::flow_between(prev, next, &self.camera, &self.params, predicted_rotation_cam, &mut self.ws)
    }

    /// Where the floor repeats, when the last pair was refused as [`NoFlowReason::RepeatingTexture`].
    pub fn repetition(&self) -> Option<flow::Repetition> {
        self.ws.repetition()
    }

    /// The last pair's counts (selected, in view, tracked, inliers, the fit's residual), also when refused.
    pub fn last_counts(&self) -> flow::PairCounts {
        self.ws.last_counts()
    }

    /// The last pair's tracks (position px, displacement px, inlier), for display.
    pub fn last_tracks(&self) -> impl Iterator<Item = (geometry::Vec2, geometry::Vec2, bool)> + '_ {
        self.ws.last_tracks()
    }
}
