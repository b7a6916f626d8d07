//! The messages that cross the radio link between the ground station and the vehicle, defined once and
//! shared by the firmware, the simulator and the log tools.
//!
//! - [`Uplink`]: ground station to vehicle: the forward camera's line measurement of each frame (solved into a
//!   pose on board, with the estimator's attitude at the frame's capture time), the downward camera's optical
//!   flow of each frame pair (derotated and scaled on board), operator commands, heartbeats, parameters, and a
//!   whole flight configuration in pieces ([`ConfigChunk`]).
//! - [`Downlink`]: vehicle to ground station: telemetry, command acknowledgements, parameter replies, the
//!   answers to the station's clock synchronisation and to a configuration upload ([`ConfigAck`]).
//!
//! All times are microseconds on the vehicle's clock.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod auth;
pub mod frame;
pub mod packed;

pub use packed::{PackedFlow, PackedTelemetry, PackedVision};

use control_core::estimator::StateEstimate;
use control_core::laws::Setpoint;
use control_core::params::ParamId;
use control_core::{Command, CommandResult, Failsafe, FlightMode, ParamReply};
use serde::{Deserialize, Serialize};
use vision_core::LineObservation;
use vision_core::flow::{FlowStats, NoFlowReason};

/// One forward-camera frame as measured by the ground station.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VisionMeasurement {
    /// Capture time of the frame (mid-exposure, us).
    pub capture_time_us: u64,
    /// Frame counter of the camera.
    pub frame_seq: u32,
    /// The line's edges, or `None` when the frame had no line.
    pub observation: Option<LineObservation>,
}

/// The optical flow of one downward-camera frame pair as measured by the ground station.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FlowMeasurement {
    /// Capture time of the earlier frame (mid-exposure, us).
    pub t_prev_us: u64,
    /// Capture time of the later frame (mid-exposure, us).
    pub t_next_us: u64,
    /// Frame counter of the later frame.
    pub frame_seq: u32,
    /// The flow's statistics, or why there was none.
    pub result: Result<FlowStats, NoFlowReason>,
}

/// Bytes of an upload a [`ConfigChunk`] carries at most.
pub const CONFIG_CHUNK_BYTES: usize = 32;

/// A piece of a flight configuration sent to the vehicle on the ground (`flight_core::config_upload`): the
/// upload is the configuration's schema key and its postcard bytes, named by their CRC-32; the pieces may come
/// in any order and more than once.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ConfigChunk {
    /// CRC-32 (ISO-HDLC) of the whole upload: names it (a piece of another upload starts that one afresh).
    pub crc32: u32,
    /// The upload's length (bytes).
    pub total_len: u16,
    /// Where this piece starts in the upload.
    pub offset: u16,
    /// How many of `bytes` belong to the upload (1 to [`CONFIG_CHUNK_BYTES`]).
    pub len: u8,
    /// The piece, padded with zeros.
    pub bytes: [u8; CONFIG_CHUNK_BYTES],
}

/// The vehicle's answer to a whole configuration upload.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ConfigAck {
    /// The upload's CRC-32 ([`ConfigChunk::crc32`]).
    pub crc32: u32,
    /// What became of it.
    pub outcome: ConfigOutcome,
}

/// What became of a configuration upload.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigOutcome {
    /// The flight stack runs on it (rebuilt from it: the estimator starts afresh). `saved_sequence`: the
    /// sequence number it was stored under in flash, so that it is loaded at the next boot; `None` when it
    /// could not be stored (the vehicle says why in its log) and it lasts until the power goes.
    Applied {
        /// The flash store's sequence number of the set.
        saved_sequence: Option<u32>,
    },
    /// Not taken; the vehicle runs on what it had.
    Refused(ConfigRefusal),
}

/// Why a configuration upload was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigRefusal {
    /// Not while armed: land and disarm first.
    Armed,
    /// The bytes do not match their CRC-32, or the pieces do not fit together (lengths, offsets).
    Damaged,
    /// A configuration of another layout (another firmware version's schema key).
    OtherLayout,
    /// The bytes do not decode as a configuration.
    Undecodable,
    /// The configuration fails the flight stack's checks (the vehicle names the field in its log; the
    /// station checks with the same code before it sends).
    Invalid,
    /// Longer than the vehicle takes.
    TooLarge,
    /// Sent over an unauthenticated link to a vehicle that takes no commands from one (no radio key
    /// provisioned, and not built with `unauthenticated-link`: docs/security.md), as its `Arm` is refused.
    Unauthenticated,
}

/// Ground station to vehicle.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Uplink {
    /// A forward-camera frame's measurement.
    Vision(VisionMeasurement),
    /// An operator command.
    Command(Command),
    /// Keeps the link alive when nothing else is sent.
    Heartbeat,
    /// Change a parameter (on the ground only).
    ParamSet {
        /// Which.
        id: ParamId,
        /// New value.
        value: f32,
    },
    /// Read a parameter.
    ParamGet(ParamId),
    /// A downward-camera frame pair's optical flow.
    Flow(FlowMeasurement),
    /// Clock synchronisation, as MAVLink's TIMESYNC: the station's clock when it sent this (us); the vehicle
    /// answers [`Downlink::TimeSync`] with its own clock, and the station estimates the offset and drift that
    /// put its capture times on the vehicle's clock.
    TimeSync {
        /// The station's clock at sending (us).
        station_time_us: u64,
    },
    /// A forward-camera frame's measurement in fewer bytes ([`packed`]): what the station sends.
    PackedVision(PackedVision),
    /// A downward-camera frame pair's optical flow in fewer bytes ([`packed`]): what the station sends.
    PackedFlow(PackedFlow),
    /// A piece of a flight configuration (on the ground only); answered by [`Downlink::ConfigAck`] once whole.
    Config(ConfigChunk),
}

impl Uplink {
    /// The line measurement this message carries, packed or not, as the vehicle uses it.
    pub fn vision(&self) -> Option<VisionMeasurement> {
        match self {
            Uplink::Vision(m) => Some(*m),
            Uplink::PackedVision(p) => Some(p.unpack()),
            _ => None,
        }
    }

    /// The flow measurement this message carries, packed or not, as the vehicle uses it.
    pub fn flow(&self) -> Option<FlowMeasurement> {
        match self {
            Uplink::Flow(m) => Some(*m),
            Uplink::PackedFlow(p) => Some(p.unpack()),
            _ => None,
        }
    }
}

/// Vehicle to ground station: what the flight code is doing.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Telemetry {
    /// Time of the control step (us).
    pub time_us: u64,
    /// Mode.
    pub mode: FlightMode,
    /// Active or last failsafe.
    pub failsafe: Option<Failsafe>,
    /// State estimate.
    pub estimate: StateEstimate,
    /// Reference.
    pub setpoint: Setpoint,
    /// Rotor speed commands (rad/s).
    pub motors_rad_s: [f32; 4],
    /// Age of the last accepted vision fix (s).
    pub fix_age_s: f32,
    /// Cost of the last control step (CPU cycles or instructions; 0 when not measured).
    pub step_cost: u32,
}

/// The vehicle's end of the radio link, reported by its link layer once a second
/// (`flight_core::radio::STATUS_PERIOD_US`): whether its frames are authenticated, and what it refused.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkStatus {
    /// Whether the frames are authenticated (a key is provisioned); false in the development mode.
    pub authenticated: bool,
    /// Arm commands refused because the link is not authenticated (development mode, a firmware built without
    /// the `unauthenticated-link` feature).
    pub arm_refused: u32,
    /// Frames that failed the framing (CRC, COBS, version, length).
    pub framing_errors: u32,
    /// Authenticated frames accepted, and refused by reason (all zero in the development mode).
    pub auth: auth::AuthCounters,
}

/// Vehicle to ground station. (Messages live on the stack and are encoded at once: no boxing without an
/// allocator, hence the size difference between variants.)
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Downlink {
    /// Periodic telemetry.
    Telemetry(Telemetry),
    /// The outcome of a command.
    CommandAck(CommandResult),
    /// The answer to a parameter request.
    Param(ParamReply),
    /// The answer to [`Uplink::TimeSync`]: the request's station time echoed, and the vehicle's clock at the
    /// control step that read it.
    TimeSync {
        /// The request's station time (us), echoed.
        station_time_us: u64,
        /// The vehicle's clock at the step that read the request (us).
        vehicle_time_us: u64,
    },
    /// Periodic telemetry in fewer bytes ([`packed`]): what the vehicle sends.
    PackedTelemetry(PackedTelemetry),
    /// The radio link's state and counters, once a second.
    LinkStatus(LinkStatus),
    /// The answer to a whole configuration upload.
    ConfigAck(ConfigAck),
    /// The flight battery, once a second (when the vehicle monitors it).
    Battery(control_core::battery::BatteryStatus),
}

impl Downlink {
    /// The telemetry this message carries, packed or not.
    pub fn telemetry(&self) -> Option<Telemetry> {
        match self {
            Downlink::Telemetry(t) => Some(*t),
            Downlink::PackedTelemetry(p) => Some(p.unpack()),
            _ => None,
        }
    }
}
