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
}

#[cfg(test)]
mod tests {
    use super::*;
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
