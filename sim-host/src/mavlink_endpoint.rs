//! A MAVLink ground control station beside a ground station (`--mavlink udp:HOST:PORT`, docs/mavlink.md): the
//! pure bridge of `ground_station::mavlink_bridge` on its UDP endpoint. The ground station feeds it what came
//! down the radio and carries out what it asks ([`GroundRequest`]); `sim-host station` does so for a vehicle
//! at the other end of a radio, `sim-host fly --mavlink` for the simulated one (its in-process station).
use anyhow::{Context, Result};
use control_core::Command;
use ground_station::mavlink_bridge::udp::MavUdp;
use ground_station::mavlink_bridge::{Bridge, MavMessage, ParamQueue, Request};
use protocol::{Downlink, Uplink};

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

/// What the ground control station asks of the ground station.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GroundRequest {
    /// An operator command (as a console key would give it).
    Command(Command),
    /// The kill (as the console's kill key).
    Kill,
    /// A message to send up the radio now (a parameter request).
    Uplink(Uplink),
}

/// The bridge and its UDP endpoint.
pub struct MavlinkEndpoint {
    bridge: Bridge,
    udp: MavUdp,
    params: ParamQueue,
    stats: MavlinkStats,
}

impl MavlinkEndpoint {
    /// Opens `udp:HOST:PORT`.
    pub fn open(spec: &str) -> Result<Self> {
        let udp = MavUdp::open(spec).map_err(anyhow::Error::msg)?;
        let stats = MavlinkStats {
            peer: spec.trim_start_matches("udp:").to_string(),
            local: udp.local_addr().context("--mavlink: the endpoint's address")?.to_string(),
            ..Default::default()
        };
        Ok(Self { bridge: Bridge::new(), udp, stats, params: ParamQueue::default() })
    }

    /// The local address the endpoint listens on.
    pub fn local_addr(&self) -> &str {
        &self.stats.local
    }

    fn send(&mut self, messages: Vec<MavMessage>) {
        self.udp.send(&messages);
    }

    /// The periodic messages (heartbeat, status) due at `now_us` (a monotonic clock of the caller's).
    pub fn tick(&mut self, now_us: u64) {
        let out = self.bridge.tick(now_us);
        self.send(out);
    }

    /// The ground station's count of refused radio frames (reported in `SYS_STATUS`).
    pub fn set_link_errors(&mut self, n: u64) {
        self.bridge.set_link_errors(n);
    }

    /// A message that came down the radio.
    pub fn downlink(&mut self, d: &Downlink) {
        let out = match (d.telemetry(), d) {
            (Some(tm), _) => self.bridge.telemetry(&tm),
            (None, Downlink::CommandAck(r)) => self.bridge.command_result(*r),
            (None, Downlink::Battery(b)) => self.bridge.battery(b),
            (None, Downlink::Param(r)) => {
                self.params.answered(r.id);
                self.bridge.param_reply(*r)
            }
            (None, _) => return,
        };
        self.send(out);
    }

    /// What the ground control station asks at `now_us`: its commands, and the next parameter request.
    pub fn poll(&mut self, now_us: u64) -> Result<Vec<GroundRequest>> {
        let mut out = Vec::new();
        for (from, m) in self.udp.receive().context("--mavlink: the ground control station's socket")? {
            let (requests, replies) = self.bridge.take(from, &m, now_us);
            self.send(replies);
            for r in requests {
                match r {
                    Request::Kill => out.push(GroundRequest::Kill),
                    Request::Command(c) => out.push(GroundRequest::Command(c)),
                    Request::ParamGet(_) | Request::ParamSet(..) => {
                        self.params.push(r);
                        continue;
                    }
                }
                self.stats.commands += 1;
            }
        }
        // Parameter requests one at a time (the vehicle answers one a step).
        if let Some(m) = self.params.next(now_us) {
            self.stats.param_requests += 1;
            out.push(GroundRequest::Uplink(m));
        }
        Ok(out)
    }

    /// What was counted, after a last heartbeat with the vehicle's last state.
    pub fn finish(mut self) -> MavlinkStats {
        let hb = self.bridge.heartbeat();
        self.udp.send(&[hb]);
        self.stats.udp = self.udp.counters();
        self.stats.bridge = self.bridge.counters();
        self.stats.param_resent = self.params.resent;
        self.stats.param_given_up = self.params.given_up;
        self.stats
    }
}
