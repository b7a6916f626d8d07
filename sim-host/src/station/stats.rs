//! What the station counted, written to `station.json`.
use crate::mavlink_endpoint::MavlinkStats;
use ground_station::v4l2::CaptureCounters;

/// What the station counted.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StationStats {
    /// Seconds the station ran.
    pub seconds: f64,
    /// Forward frames received, measured (the line found), without a line, and dropped before the clock was
    /// known.
    pub forward_frames: u64,
    /// Times a camera stream stalled (no frame for [`super::CAMERA_STALL_S`] after it had sent one): forward, down.
    pub camera_stalls: [u64; 2],
    /// What each camera (forward, down) delivered and lost at the source: a live camera's buffers, frames
    /// the kernel numbered but the station never got, buffers flagged damaged, buffers that did not decode.
    pub camera_counters: [CaptureCounters; 2],
    /// Forward frames in which the line was found.
    pub forward_measured: u64,
    /// Forward frames that arrived before the vehicle's clock was known (not sent).
    pub frames_before_clock: u64,
    /// Downward frames received.
    pub down_frames: u64,
    /// Flow measurements sent.
    pub flow_sent: u64,
    /// Uplink messages sent, by kind.
    pub uplink_vision: u64,
    /// Flow messages.
    pub uplink_flow: u64,
    /// Commands (with retries).
    pub uplink_commands: u64,
    /// Heartbeats and time-sync requests.
    pub uplink_other: u64,
    /// Telemetry messages received.
    pub telemetry: u64,
    /// Command acknowledgements received, with the refusals' reasons.
    pub command_acks: Vec<String>,
    /// Answers to configuration uploads (what became of each).
    pub config_acks: Vec<String>,
    /// The vehicle's last battery report.
    pub vehicle_battery: Option<control_core::battery::BatteryStatus>,
    /// Time-sync answers received.
    pub time_sync_answers: u64,
    /// Of those, refused by the clock sync: arriving before their request left, or slower than its limit.
    pub time_sync_refused: [u64; 2],
    /// The clock sync's error bound at the end (ms).
    pub clock_bound_ms: Option<f64>,
    /// The vehicle's modes as the telemetry reported them, with the station's time (s).
    pub modes: Vec<(f64, String)>,
    /// Bytes sent and received on the radio.
    pub link_bytes: [u64; 2],
    /// The radio's decoder: frames refused by reason.
    pub link_decoder: protocol::frame::DecodeCounters,
    /// How the radio is secured: `hmac-sha256-48`, or `none (development)`.
    pub link_security: String,
    /// The downlink's authentication: sessions, frames accepted and refused by reason (docs/security.md).
    pub auth: protocol::auth::AuthCounters,
    /// Hellos sent (keyed link): until the vehicle answered, and again after a session went quiet.
    pub hellos_sent: u64,
    /// New handshakes started because no authentic downlink came for [`super::REHELLO_AFTER_S`] (a vehicle that
    /// rebooted, or whose session a replayed hello replaced while it was disarmed).
    pub rehellos: u64,
    /// The vehicle's own report of its radio, the last received (`Downlink::LinkStatus`, once a second):
    /// whether it authenticates, arm commands it refused, and its uplink's counters by reason.
    pub vehicle_link: Option<protocol::LinkStatus>,
    /// Median and 95th percentile of the time from a forward frame's arrival to its measurement leaving on
    /// the radio (ms).
    pub frame_to_uplink_ms: [f64; 2],
    /// The operator's own commands (the console's keys), with the station's time (s).
    pub operator_commands: Vec<(f64, String)>,
    /// The compact mode: whether the vehicle took the telemetry period (`None` without the mode), and the
    /// frames not measured by its choice (forward, down).
    pub compact_announced: Option<bool>,
    /// Frames left out by the compact mode (forward, down).
    pub compact_skipped: [u64; 2],
    /// Why the station stopped.
    pub ended: String,
    /// Records in the station's flight log.
    pub log_records: u64,
    /// The MAVLink ground control station's endpoint, when there is one: what the bridge took and sent.
    pub mavlink: Option<MavlinkStats>,
    /// The live view's counts (`--live`, `crate::live::LiveStats`), when there is one.
    pub live: Option<serde_json::Value>,
}
