//! The cameras' frames rendered and measured on the thread pool while the simulation goes on.
//!
//! The ground station's measurements reach the flight code some time after the capture
//! (`forward_camera.latency_s`, 50 ms in the paper scenario, a frame and a half at 30 Hz;
//! `down_camera.latency_s`, 30 ms, nearly two frames at 60 Hz). The simulation therefore goes on stepping the
//! physics, the flight code and the other camera while the pool renders a frame and runs the detector or the
//! flow tracker on it; the simulator waits for the result (`PoolJob::join`) before the measurement is due, or
//! at the same camera's next capture, whichever comes first. The measurement's message is queued on the
//! simulated link at the capture, as before, and completed at the join (a downward pair that gives no flow
//! takes its message back): the link's random draws and the queue's order are those of a frame measured at
//! once, so a flight is bit for bit the same either way
//! (`the_pipelined_cameras_fly_bit_for_bit_as_the_immediate_ones`, below; the README flight's
//! `trajectory.csv`, `flow.csv`, plots and `flight.log` were compared byte for byte).
//!
//! Used only where nothing else needs the frame at the capture: not for a separate station's stream, a live
//! view, a log with frames, a frozen camera or a corrupting link (and for the downward camera not while the
//! link drops messages); those measure at once. Not inside a sweep either, whose runs already fill the pool
//! (a run that waited there for its own frame could wait for a thread that waits too).
use crate::downward::GroundFlow;
use crate::imageio::RgbImage;
use crate::render::{DownPose, DownRenderer, DownSettings, ForwardRenderer, RenderSettings};
use crate::vision::GroundVision;
use geometry::{Mat3, Vec3};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, sync_channel};
use vision_core::flow::{FlowStats, NoFlowReason};
use vision_core::{LineObservation, NoTargetReason, RowTiming};

/// What the detector made of a frame.
pub type Detection = Result<LineObservation, NoTargetReason>;

/// Work on the thread pool whose result the simulation collects later.
pub struct PoolJob<T> {
    result: Receiver<std::thread::Result<T>>,
}

impl<T: Send + 'static> PoolJob<T> {
    /// Starts `work` on the pool.
    pub fn spawn(work: impl FnOnce() -> T + Send + 'static) -> Self {
        let (tx, result) = sync_channel(1);
        rayon::spawn(move || {
            let out = catch_unwind(AssertUnwindSafe(work));
            // The receiver is gone only if the simulation was dropped before the work came back: nothing
            // waits for it then.
            if tx.send(out).is_err() {}
        });
        Self { result }
    }

    /// Waits for the result. A panic of the work is raised here, on the simulation's thread.
    pub fn join(self) -> T {
        match self.result.recv() {
            Ok(Ok(done)) => done,
            Ok(Err(panic)) => std::panic::resume_unwind(panic),
            Err(_) => panic!("a camera worker ended without a result"),
        }
    }
}

/// One forward frame in the works.
pub struct ForwardJob {
    /// The detector (with what it learned from this frame), its result, and the frame's buffer for the next.
    pub work: PoolJob<(GroundVision, Detection, RgbImage)>,
    /// When its measurement is due at the flight code (us).
    pub deliver_us: u64,
    /// Its capture time (us): with the sequence number, its message on the link.
    pub capture_us: u64,
    /// Its sequence number.
    pub frame_seq: u32,
}

impl ForwardJob {
    /// Renders at `r_wc`, `center` with `settings` into `img` and runs `vision` on it, on the thread pool.
    #[allow(clippy::too_many_arguments)]
    pub fn spawn(
        renderer: Arc<ForwardRenderer>,
        mut vision: GroundVision,
        mut img: RgbImage,
        r_wc: Mat3,
        center: Vec3,
        settings: RenderSettings,
        timing: Option<RowTiming>,
        capture_us: u64,
        frame_seq: u32,
        deliver_us: u64,
    ) -> Self {
        let work = PoolJob::spawn(move || {
            renderer.render_into(&r_wc, center, &settings, &mut img);
            let detection = vision.detect_timed(&img, timing.as_ref());
            (vision, detection, img)
        });
        Self { work, deliver_us, capture_us, frame_seq }
    }
}

/// What the flow tracker made of a downward frame: nothing for a first frame, else a flow or why none.
pub type FlowResult = Option<Result<FlowStats, NoFlowReason>>;

/// The truth over a downward frame pair: the later frame's time (us), the attitude at mid-interval (world
/// from body) and the mean velocity (world, m/s).
pub type FlowTruth = (u64, [[f64; 3]; 3], [f64; 3]);

/// One downward frame in the works.
pub struct DownJob {
    /// The tracker (with this frame as its previous one) and its result.
    pub work: PoolJob<(GroundFlow, FlowResult)>,
    /// When its measurement is due at the flight code (us).
    pub deliver_us: u64,
    /// Its capture time (us): with the sequence number, its message on the link.
    pub capture_us: u64,
    /// Its sequence number.
    pub frame_seq: u32,
    /// Whether a message waits for it on the link (a previous frame exists, the camera was not dropped).
    pub queued: bool,
    /// The truth over the pair, kept when the pair gives a flow.
    pub truth: Option<FlowTruth>,
}

impl DownJob {
    /// Renders the downward camera at `pose` with `settings` and adds the frame to `flow`, on the pool.
    pub fn spawn(
        renderer: Arc<DownRenderer>,
        mut flow: GroundFlow,
        pose: DownPose,
        settings: DownSettings,
        predicted_rotation_cam: Vec3,
    ) -> PoolJob<(GroundFlow, FlowResult)> {
        PoolJob::spawn(move || {
            let img = renderer.render(&pose, &settings);
            let result = flow.add(&img, predicted_rotation_cam);
            (flow, result)
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::scenario::{FaultConfig, FaultKind, Scenario};
    use crate::sil::{CameraMode, Sil};

    /// Flies `secs` of `s`; returns the records, the frames' counts and flow scores, and the frames of each
    /// camera pipelined.
    fn fly(s: &Scenario, secs: f64) -> (Vec<crate::sil::Record>, String, [u64; 2]) {
        let mut sil = Sil::new(s, 4, CameraMode::Rendered).unwrap();
        let st = sil.run(secs, |_| {});
        let flows: Vec<_> = sil.flow_records().iter().map(|r| (r.t_s, r.measured, r.std_m_s)).collect();
        let counts = format!(
            "{} {} {} {} {} {:?} {:?}",
            st.frames,
            st.frames_solved,
            st.frames_rejected,
            st.ground_no_target.to_json(),
            st.down_frames,
            st.flow_rms_error_m_s,
            flows
        );
        (sil.records().to_vec(), counts, [sil.pipelined_frames(), sil.pipelined_down_frames()])
    }

    #[test]
    fn the_pipelined_cameras_fly_bit_for_bit_as_the_immediate_ones() {
        let mut s = Scenario::paper();
        // With the vision and the flow lost for a while and the link down for a moment: the measurements
        // that are never sent are still measured, and the link's losses fall on the same messages. A frozen
        // camera and a corrupting link measure at once (the frozen frame and the corrupted bytes are the
        // measurement's): were they pipelined, the flight would differ.
        s.faults = vec![
            FaultConfig { start_s: 3.0, duration_s: 0.5, kind: FaultKind::VisionDropout },
            FaultConfig { start_s: 2.0, duration_s: 0.4, kind: FaultKind::FlowDropout },
            FaultConfig { start_s: 4.2, duration_s: 0.3, kind: FaultKind::LinkLoss },
            FaultConfig { start_s: 3.6, duration_s: 0.4, kind: FaultKind::VisionFreeze },
            FaultConfig {
                start_s: 5.0,
                duration_s: 0.5,
                kind: FaultKind::LinkCorruption { byte_error_rate: 0.01 },
            },
        ];
        // On the test's own thread frames go to the pool; on a pool thread (as in a sweep) they are measured
        // at once.
        let piped = fly(&s, 6.0);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        let immediate = pool.install(|| fly(&s, 6.0));
        assert!(piped.2[0] > 150 && piped.2[1] > 300, "{:?} frames pipelined", piped.2);
        assert_eq!(immediate.2, [0, 0]);
        assert_eq!(piped.1, immediate.1);
        assert_eq!(piped.0.len(), immediate.0.len());
        for (a, b) in piped.0.iter().zip(&immediate.0) {
            assert_eq!(format!("{a:?}"), format!("{b:?}"));
        }
    }
}
