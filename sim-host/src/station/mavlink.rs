//! The station's MAVLink side (`sim-host station --mavlink udp:HOST:PORT`, docs/mavlink.md): the pure bridge
//! of `ground_station::mavlink_bridge` and its UDP endpoint, fed by the station's loop with what came down
//! the radio, and giving it the ground control station's requests.
use anyhow::{Context, Result};
use ground_station::mavlink_bridge::udp::MavUdp;
use ground_station::mavlink_bridge::{Bridge, MavMessage, ParamQueue};

/// What the MAVLink endpoint counted.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct MavlinkStats {
    /// The ground control station's address.
    pub peer: String,
    /// The local address the endpoint listened on.
    pub local: String,
    /// The datagrams and messages.
    pub udp: ground_station::mavlink_bridge::udp::UdpCounters,
    /// What the bridge took, refused and gave up on.
    pub bridge: ground_station::mavlink_bridge::BridgeCounters,
    /// Operator commands that came from the ground control station (kills included).
    pub commands: u64,
    /// Parameter reads and changes sent to the vehicle for it (one at a time, resends included).
    pub param_requests: u64,
    /// Of those, resent because the vehicle's answer did not come.
    pub param_resent: u64,
    /// Parameter requests given up after their tries.
    pub param_given_up: u64,
}

/// The station's MAVLink side: the bridge and its UDP endpoint, sending what the bridge makes at once.
pub(super) struct MavlinkSide {
    pub(super) bridge: Bridge,
    pub(super) udp: MavUdp,
    pub(super) stats: MavlinkStats,
    pub(super) params: ParamQueue,
}

impl MavlinkSide {
    pub(super) fn open(spec: &str) -> Result<Self> {
        let udp = MavUdp::open(spec).map_err(anyhow::Error::msg)?;
        let stats = MavlinkStats {
            peer: spec.trim_start_matches("udp:").to_string(),
            local: udp.local_addr().context("--mavlink: the endpoint's address")?.to_string(),
            ..Default::default()
        };
        Ok(Self { bridge: Bridge::new(), udp, stats, params: ParamQueue::default() })
    }

    pub(super) fn send(&mut self, messages: Vec<MavMessage>) {
        self.udp.send(&messages);
    }

    pub(super) fn finish(mut self) -> MavlinkStats {
        // A last heartbeat with the vehicle's last state.
        let hb = self.bridge.heartbeat();
        self.udp.send(&[hb]);
        self.stats.udp = self.udp.counters();
        self.stats.bridge = self.bridge.counters();
        self.stats.param_resent = self.params.resent;
        self.stats.param_given_up = self.params.given_up;
        self.stats
    }
}
