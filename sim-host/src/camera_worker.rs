//! The forward camera's frame rendered and measured on the thread pool while the simulation goes on.
//!
//! The ground station's line measurement reaches the flight code `forward_camera.latency_s` after the capture
//! (50 ms in the paper scenario, a frame and a half at 30 Hz). The simulation therefore goes on stepping the
//! physics, the flight code and the downward camera while the pool renders the frame and runs the detector on
//! it; the simulator waits for the result (`ForwardJob::join`) before the measurement is due, or at the next
//! capture, whichever comes first. The measurement's message is queued on the simulated link at the capture,
//! as before, with its observation filled in at the join: the link's random draws and the queue's order are
//! those of a frame measured at once, so a flight is bit for bit the same either way
//! (`the_pipelined_forward_camera_flies_bit_for_bit_as_the_immediate_one`, below; the README's flight's
//! `trajectory.csv`, `flow.csv`, plots and `flight.log` were compared byte for byte).
//!
//! Used only where nothing else needs the frame at the capture: not for a separate station's stream, a live
//! view, a log with frames, a frozen camera or a corrupting link (those measure at once), and not inside a
//! sweep, whose runs already fill the pool (a run that waited there for its own frame could wait for a
//! thread that waits too).
use crate::imageio::RgbImage;
use crate::render::{ForwardRenderer, RenderSettings};
use crate::vision::GroundVision;
use geometry::{Mat3, Vec3};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, sync_channel};
use vision_core::{LineObservation, NoTargetReason, RowTiming};

/// What the detector made of a frame.
pub type Detection = Result<LineObservation, NoTargetReason>;

/// One forward frame in the works.
pub struct ForwardJob {
    result: Receiver<std::thread::Result<(GroundVision, Detection)>>,
    /// When its measurement is due at the flight code (us).
    pub deliver_us: u64,
    /// Its capture time (us): with the sequence number, its message on the link.
    pub capture_us: u64,
    /// Its sequence number.
    pub frame_seq: u32,
}

impl ForwardJob {
    /// Renders at `r_wc`, `center` with `settings` and runs `vision` on the image, on the thread pool.
    #[allow(clippy::too_many_arguments)]
    pub fn spawn(
        renderer: Arc<ForwardRenderer>,
        mut vision: GroundVision,
        r_wc: Mat3,
        center: Vec3,
        settings: RenderSettings,
        timing: Option<RowTiming>,
        capture_us: u64,
        frame_seq: u32,
        deliver_us: u64,
    ) -> Self {
        let (tx, result) = sync_channel(1);
        rayon::spawn(move || {
            let out = catch_unwind(AssertUnwindSafe(move || {
                let img: RgbImage = renderer.render(&r_wc, center, &settings);
                let detection = vision.detect_timed(&img, timing.as_ref());
                (vision, detection)
            }));
            // The receiver is gone only if the simulation was dropped before its frame came back: nothing
            // waits for it then.
            if tx.send(out).is_err() {}
        });
        Self { result, deliver_us, capture_us, frame_seq }
    }

    /// Waits for the frame: the detector (with what it learned from this frame) and its result. A panic of
    /// the worker is raised here, on the simulation's thread.
    pub fn join(self) -> (GroundVision, Detection) {
        match self.result.recv() {
            Ok(Ok(done)) => done,
            Ok(Err(panic)) => std::panic::resume_unwind(panic),
            Err(_) => panic!("the forward camera's worker ended without a result"),
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::scenario::{FaultConfig, FaultKind, Scenario};
    use crate::sil::{CameraMode, Sil};

    /// Flies `secs` of `s`; returns the records, the frames and no-target counts, and the frames pipelined.
    fn fly(s: &Scenario, secs: f64) -> (Vec<crate::sil::Record>, String, u64) {
        let mut sil = Sil::new(s, 4, CameraMode::Rendered).unwrap();
        let st = sil.run(secs, |_| {});
        let counts = format!(
            "{} {} {} {}",
            st.frames,
            st.frames_solved,
            st.frames_rejected,
            st.ground_no_target.to_json()
        );
        (sil.records().to_vec(), counts, sil.pipelined_frames())
    }

    #[test]
    fn the_pipelined_forward_camera_flies_bit_for_bit_as_the_immediate_one() {
        let mut s = Scenario::paper();
        // With the vision lost for a while and the link down for a moment: the measurements that are never
        // sent are still measured, and the link's losses fall on the same messages.
        s.faults = vec![
            FaultConfig { start_s: 3.0, duration_s: 0.5, kind: FaultKind::VisionDropout },
            FaultConfig { start_s: 4.2, duration_s: 0.3, kind: FaultKind::LinkLoss },
        ];
        // On the test's own thread frames go to the pool; on a pool thread (as in a sweep) they are measured
        // at once.
        let piped = fly(&s, 6.0);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        let immediate = pool.install(|| fly(&s, 6.0));
        assert!(piped.2 > 150, "{} frames pipelined", piped.2);
        assert_eq!(immediate.2, 0);
        assert_eq!(piped.1, immediate.1);
        assert_eq!(piped.0.len(), immediate.0.len());
        for (a, b) in piped.0.iter().zip(&immediate.0) {
            assert_eq!(format!("{a:?}"), format!("{b:?}"));
        }
    }
}
