//! The station's cameras: each read on its own thread, its stalls watched, its forward frames turned into the
//! image the vision measures and into the measurement that goes up the radio.
use crate::imageio::RgbImage;
use crate::vision::GroundVision;
use anyhow::{Result, bail};
use ground_station::source::{SourceWant, now_unix_us};
use ground_station::stream::Frame;
use ground_station::v4l2::CaptureCounters;
use protocol::VisionMeasurement;
use std::sync::mpsc;

/// A camera frame as it arrived: the frame, its arrival time on the station's clock, and the source's
/// counters then.
pub(super) type Arrival = (Frame, u64, CaptureCounters);

/// A camera opened and read on its own thread (a camera that does not answer does not hold up the radio):
/// frames with their arrival time; the error that ended it.
pub(super) fn camera_thread(
    spec: &str,
    want: SourceWant,
    what: &'static str,
) -> mpsc::Receiver<Result<Arrival, String>> {
    let (tx, rx) = mpsc::sync_channel(8);
    let spec = spec.to_string();
    std::thread::spawn(move || {
        let mut reader = match ground_station::source::open(&spec, want) {
            Ok(r) => r,
            Err(e) => {
                let _closed = tx.send(Err(format!("--{what}: {e}")));
                return;
            }
        };
        loop {
            match reader.next_frame() {
                Ok(Some(f)) => {
                    if tx.send(Ok((f, now_unix_us(), reader.counters()))).is_err() {
                        return;
                    }
                }
                Ok(None) => {
                    let _closed = tx.send(Err(format!("the {what} stream ended")));
                    return;
                }
                Err(e) => {
                    let _closed = tx.send(Err(format!("the {what} stream: {e}")));
                    return;
                }
            }
        }
    });
    rx
}

/// A forward camera's frame as the image the vision measures: RGB, of the calibration's size.
pub fn forward_image(f: Frame, camera: &vision_core::CameraModel) -> Result<RgbImage> {
    if f.channels != 3 {
        bail!("the forward stream sent a {}-channel frame; RGB expected", f.channels);
    }
    ground_station::calib::check_size(camera, f.width, f.height)
        .map_err(|e| anyhow::anyhow!("the forward camera: {e}"))?;
    Ok(RgbImage { width: f.width, height: f.height, data: f.data })
}

/// The measurement of a forward frame captured at `vehicle_us` on the vehicle's clock (the line's edges, or
/// none), as it goes up the radio; a rolling shutter's rows corrected when `timing` is given.
pub fn measure_forward(
    vision: &mut GroundVision,
    img: &RgbImage,
    vehicle_us: u64,
    frame_seq: u32,
    timing: Option<&vision_core::RowTiming>,
) -> VisionMeasurement {
    VisionMeasurement {
        capture_time_us: vehicle_us,
        frame_seq,
        observation: vision.detect_timed(img, timing).ok(),
    }
}

/// A camera silent for this long is stalled (counted once per stall; 15 frames at 30 Hz).
pub const CAMERA_STALL_S: f64 = 0.5;

/// Stalls of one camera: gaps between frames longer than [`CAMERA_STALL_S`].
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct StallWatch {
    last_frame_s: Option<f64>,
    pub(super) stalled: bool,
}

impl StallWatch {
    pub(super) fn frame(&mut self, t: f64) {
        self.last_frame_s = Some(t);
        self.stalled = false;
    }

    /// Whether a new stall began at `t` (the camera had sent a frame before).
    pub(super) fn check(&mut self, t: f64) -> bool {
        let begun = !self.stalled && self.last_frame_s.is_some_and(|l| t - l > CAMERA_STALL_S);
        self.stalled |= begun;
        begun
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_camera_gap_longer_than_the_stall_limit_counts_once_until_frames_come_back() {
        let mut w = StallWatch::default();
        // Nothing yet: a camera that never sent is not stalled (its error or the clock says why).
        assert!(!w.check(10.0));
        w.frame(1.0);
        assert!(!w.check(1.0 + CAMERA_STALL_S * 0.9));
        assert!(w.check(1.0 + CAMERA_STALL_S * 1.1));
        assert!(!w.check(1.0 + CAMERA_STALL_S * 3.0), "one stall, counted once");
        assert!(w.stalled);
        w.frame(5.0);
        assert!(!w.stalled);
        assert!(w.check(5.0 + CAMERA_STALL_S * 1.1), "a second stall");
    }
}
