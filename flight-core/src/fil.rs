//! Firmware in the loop: the messages between the simulator and the flight firmware running in an emulator.
//!
//! The firmware's radio UART carries them instead of the radio's plain [`Uplink`] and [`Downlink`] frames,
//! with the same framing (`protocol::frame`: COBS, CRC-16, wire version). Lockstep: for each control period the
//! simulator sends the radio messages that arrived ([`FilToFc::Link`]) and then the sensors ([`FilToFc::Step`]);
//! the firmware runs [`crate::FlightStack::step`] and answers with the radio messages it sent
//! ([`FcToFil::Link`]) and then the step's report and its cost ([`FcToFil::Step`]); then it runs the background
//! work ([`crate::FlightStack::solve_pending`]) before it reads the next message, as the simulator does after
//! its step. Nothing else runs in between, so the run is a pure function of the inputs, as in the simulator.
use control_core::estimator::ImuSample;
use geometry::Vec3;
use protocol::{Downlink, Uplink};

use crate::StepReport;

/// IMU samples per step at most (1 kHz IMU, 500 Hz control: two).
pub const MAX_IMU_PER_STEP: usize = 4;

/// One control period's sensors.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SensorStep {
    /// Time of the step (us, vehicle clock).
    pub time_us: u64,
    /// IMU samples since the previous step, oldest first.
    pub imu: heapless::Vec<ImuSample, MAX_IMU_PER_STEP>,
    /// A new magnetometer reading (body frame), if any.
    pub mag: Option<Vec3>,
    /// An external land detector's verdict (the recorded vehicle's, in imported logs); `None` in flight.
    pub landed: Option<bool>,
    /// A new barometric pressure altitude (m, any offset), if any.
    pub baro_m: Option<f32>,
}

/// Simulator to flight computer.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FilToFc {
    /// A radio message from the ground station, delivered before the next step.
    Link(Uplink),
    /// The sensors of one control period: run the step and answer.
    Step(SensorStep),
    /// The run is over: report and stop.
    Stop,
    /// Measure the keyed link's cost per frame ([`measure_auth_cost`]) and answer [`FcToFil::AuthCost`].
    AuthCost,
    /// The pilot's transmitter for the next step (sent before its `Step` when a receiver has been heard).
    Pilot(control_core::pilot::PilotInput),
    /// A reading of the flight battery for the next step.
    Battery(control_core::battery::BatteryReading),
}

/// Flight computer to simulator.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FcToFil {
    /// Booted, flight stack built, waiting for steps.
    Hello {
        /// The link's wire version.
        wire_version: u8,
    },
    /// A radio message the flight code sent (telemetry, acknowledgements, parameter replies).
    Link(Downlink),
    /// The step's outputs.
    Step {
        /// What the step returned.
        report: StepReport,
        /// Its cost: core clock cycles (under the emulator's instruction counting, SysTick counts of the
        /// 168 MHz clock; see the firmware's docs).
        cost_cycles: u32,
        /// The cost of the background work (pose solves) run after the previous step, in the same unit.
        background_cycles: u32,
        /// Frames solved by that background work.
        background_solves: u8,
    },
    /// The answer to [`FilToFc::AuthCost`].
    AuthCost(AuthCost),
}

/// The keyed link's cost on the flight computer (`protocol::auth`, docs/security.md), per frame, in the
/// board's cycle counter's unit (under the emulator's instruction counting, as [`FcToFil::Step`]'s costs).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, postcard_schema::Schema,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AuthCost {
    /// Taking a station's hello and sealing the welcome (the session key derived).
    pub handshake: u32,
    /// Opening one uplink frame: a packed line measurement with four edges, a packed flow, a command.
    pub open: [u32; 3],
    /// Sealing one downlink frame: packed telemetry, a command's acknowledgement.
    pub seal: [u32; 2],
    /// Frames that did not open as they should: 0 unless the code is broken.
    pub failures: u8,
}

/// Measures [`AuthCost`] with `cycles` (the board's free-running cycle counter): a station's side is played
/// here to make the frames; only the vehicle's work is timed.
pub fn measure_auth_cost(mut cycles: impl FnMut() -> u32) -> AuthCost {
    use protocol::auth::{Opened, Role, SecureLink};
    use protocol::frame::{MAX_FRAME, cobs_decode_in_place};
    use protocol::packed::{PackedFlow, PackedTelemetry, PackedVision};
    const KEY: [u8; 32] = [0x5A; 32];
    let mut cost = AuthCost::default();
    let mut station = SecureLink::new(Role::Station, KEY);
    let mut vehicle = SecureLink::new(Role::Vehicle, KEY);
    let mut out = [0u8; MAX_FRAME];
    let mut body = [0u8; MAX_FRAME];
    // A frame's body as the decoder gives it (COBS undone, no delimiter).
    fn unframe(frame: &[u8], body: &mut [u8; MAX_FRAME]) -> usize {
        let n = frame.len().saturating_sub(1).min(body.len());
        body[..n].copy_from_slice(&frame[..n]);
        cobs_decode_in_place(&mut body[..n]).unwrap_or(0)
    }
    fn fail(ok: bool, c: &mut AuthCost) {
        if !ok {
            c.failures = c.failures.saturating_add(1);
        }
    }
    // The handshake.
    let n = match station.hello([1; 16], &mut out) {
        Ok(f) => unframe(f, &mut body),
        Err(_) => 0,
    };
    let t0 = cycles();
    let started =
        matches!(vehicle.open::<Uplink>(&body[..n], 0, false, || [2; 16]), Ok(Opened::SessionStarted));
    let welcome_ok = vehicle.welcome(&mut out).is_ok();
    cost.handshake = cycles().wrapping_sub(t0);
    fail(started && welcome_ok, &mut cost);
    let n = match vehicle.welcome(&mut out) {
        Ok(f) => unframe(f, &mut body),
        Err(_) => 0,
    };
    let ok = matches!(station.open::<Downlink>(&body[..n], 0, false, || [0; 16]), Ok(Opened::SessionStarted));
    fail(ok, &mut cost);
    // Uplink frames, opened.
    let e = vision_core::EdgeStats {
        centroid: geometry::Vec2::new(0.1234, -0.2345),
        normal: geometry::Vec2::new(0.0123, 0.9999),
        count: 612,
        spread: 0.35,
        rms: 0.0012,
    };
    let vision = Uplink::PackedVision(PackedVision::pack(&protocol::VisionMeasurement {
        capture_time_us: 31_234_567,
        frame_seq: 937,
        observation: Some(vision_core::LineObservation {
            top: e,
            bottom: e,
            start_end: Some(e),
            finish_end: Some(e),
        }),
    }));
    let flow = Uplink::PackedFlow(PackedFlow::pack(&protocol::FlowMeasurement {
        t_prev_us: 10_000_000,
        t_next_us: 10_016_667,
        frame_seq: 600,
        result: Ok(vision_core::flow::FlowStats {
            flow: geometry::Vec2::new(-0.0123, 0.0041),
            predicted_rotation: Vec3::new(0.001, -0.002, 0.0005),
            mean_pos: geometry::Vec2::new(0.01, -0.02),
            mean_sq: [0.09, 0.05, -0.001],
            inliers: 44,
            selected: 48,
            residual_rms: 0.0004,
            median_flow_px: geometry::Vec2::new(-1.7, 0.57),
            quality: 44.0 / 48.0,
        }),
    }));
    let command = Uplink::Command(control_core::Command::Arm);
    for (k, m) in [vision, flow, command].iter().enumerate() {
        let n = match station.seal(m, &mut out) {
            Ok(f) => unframe(f, &mut body),
            Err(_) => 0,
        };
        let t0 = cycles();
        let got = vehicle.open::<Uplink>(&body[..n], 0, true, || [2; 16]);
        cost.open[k] = cycles().wrapping_sub(t0);
        fail(got == Ok(Opened::Message(*m)), &mut cost);
    }
    // Downlink frames, sealed.
    let telemetry = Downlink::PackedTelemetry(PackedTelemetry::pack(&protocol::Telemetry {
        time_us: 12_345_000,
        mode: control_core::FlightMode::Tracking,
        failsafe: None,
        estimate: control_core::estimator::StateEstimate::default(),
        setpoint: control_core::laws::Setpoint::default(),
        motors_rad_s: [812.5, 799.1, 805.0, 820.3],
        fix_age_s: 0.021,
        step_cost: 41_234,
    }));
    let ack = Downlink::CommandAck(control_core::CommandResult::Accepted(control_core::Command::Arm));
    for (k, m) in [telemetry, ack].iter().enumerate() {
        let t0 = cycles();
        let sealed = vehicle.seal(m, &mut out).map(|f| f.len());
        cost.seal[k] = cycles().wrapping_sub(t0);
        let n = match sealed {
            Ok(len) => unframe(&out[..len], &mut body),
            Err(_) => 0,
        };
        let got = station.open::<Downlink>(&body[..n], 0, false, || [0; 16]);
        fail(got == Ok(Opened::Message(*m)), &mut cost);
    }
    cost
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_auth_cost_measurement_opens_and_seals_every_frame() {
        // A counter that ticks once a read: every timed section reads it twice, so each cost is 1.
        let mut t = 0u32;
        let c = measure_auth_cost(|| {
            t += 1;
            t
        });
        assert_eq!(c.failures, 0, "{c:?}");
        assert_eq!((c.handshake, c.open, c.seal), (1, [1; 3], [1; 2]));
    }
    use crate::{FlightConfig, FlightStack, StepInput};
    use protocol::frame::{Decoder, MAX_FRAME, encode};

    #[test]
    fn the_largest_messages_fit_one_frame_and_round_trip() {
        let mut stack = FlightStack::new(FlightConfig::paper()).unwrap();
        let imu = ImuSample { time_us: 2000, gyro_rad_s: [0.01, -0.02, 0.03], accel_m_s2: [0.1, -0.2, 9.8] };
        let out = stack.step(&StepInput {
            time_us: 2000,
            imu: &[imu],
            mag: None,
            baro_m: None,
            uplink: &[],
            landed: None,
            pilot: None,
            battery: None,
        });
        let mut report = out.report();
        // Fill the optional parts, as the largest step reply would have them.
        report.flow = Some(crate::flow::FlowOutcome::NoGyro);
        report.param_reply = Some(stack.control().get_param(control_core::params::ParamId::TrajectorySpeed));
        report.control.status.failsafe = Some(control_core::Failsafe::VisionLost);
        let msgs = [
            FcToFil::Step { report, cost_cycles: 123_456, background_cycles: u32::MAX, background_solves: 2 },
            FcToFil::Hello { wire_version: protocol::frame::WIRE_VERSION },
        ];
        let mut dec = Decoder::new();
        for m in msgs {
            let mut buf = [0u8; MAX_FRAME];
            let f = encode(&m, &mut buf).unwrap();
            // Measured 272 bytes for the step reply: room left in a 512-byte frame for the larger outcomes.
            assert!(f.len() <= 400, "{} bytes", f.len());
            let got: std::vec::Vec<_> = f.iter().filter_map(|b| dec.push::<FcToFil>(*b)).collect();
            assert_eq!(got, std::vec![Ok(m)]);
        }
        let step = FilToFc::Step(SensorStep {
            time_us: 4000,
            imu: heapless::Vec::from_slice(&[imu; MAX_IMU_PER_STEP]).unwrap(),
            mag: Some(Vec3::new(0.2, -0.05, -0.4)),
            landed: None,
            baro_m: Some(1234.5),
        });
        let mut buf = [0u8; MAX_FRAME];
        let f = encode(&step, &mut buf).unwrap();
        let got: std::vec::Vec<_> = f.iter().filter_map(|b| dec.push::<FilToFc>(*b)).collect();
        assert_eq!(got, std::vec![Ok(step)]);
    }
}
