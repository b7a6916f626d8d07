//! MAVLink over UDP, as QGroundControl and MAVProxy speak it: `udp:HOST:PORT` names the ground control
//! station's port (QGroundControl listens on 14550). The bridge sends there and answers whoever sends to it
//! from that address. It binds the loopback interface when the ground control station is on this machine, so
//! no other machine reaches the vehicle through it; any other HOST binds all interfaces (the ground control
//! station runs elsewhere: put the station and it on a network you trust, docs/mavlink.md).
use super::{COMPONENT_ID, MavMessage, SYSTEM_ID};
use std::io::ErrorKind;
use std::net::{Ipv4Addr, Ipv6Addr, SocketAddr, ToSocketAddrs, UdpSocket};

/// What the transport counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct UdpCounters {
    /// Datagrams sent.
    pub sent: u64,
    /// Datagrams received from the ground control station.
    pub received: u64,
    /// MAVLink messages parsed out of them.
    pub messages: u64,
    /// Datagrams (or their tails) that held no valid MAVLink message of the common dialect (bad CRC, unknown
    /// message id, truncated).
    pub unparsable: u64,
    /// Datagrams from another address than the ground control station's, dropped.
    pub foreign: u64,
    /// Sends the operating system refused (the ground control station not listening yet, for instance).
    pub send_errors: u64,
}

/// A MAVLink 2 endpoint on UDP.
#[derive(Debug)]
pub struct MavUdp {
    socket: UdpSocket,
    peer: SocketAddr,
    sequence: u8,
    counters: UdpCounters,
}

/// The local address to bind for a ground control station at `peer`: the loopback interface when it is on
/// this machine, every interface otherwise; a port the system chooses.
pub fn bind_address(peer: &SocketAddr) -> SocketAddr {
    match (peer.ip().is_loopback(), peer) {
        (true, SocketAddr::V4(_)) => (Ipv4Addr::LOCALHOST, 0).into(),
        (true, SocketAddr::V6(_)) => (Ipv6Addr::LOCALHOST, 0).into(),
        (false, SocketAddr::V4(_)) => (Ipv4Addr::UNSPECIFIED, 0).into(),
        (false, SocketAddr::V6(_)) => (Ipv6Addr::UNSPECIFIED, 0).into(),
    }
}

/// Parses `udp:HOST:PORT` into the ground control station's address.
pub fn parse_spec(spec: &str) -> Result<SocketAddr, String> {
    let rest = spec.strip_prefix("udp:").ok_or_else(|| {
        format!("--mavlink {spec:?}: expected udp:HOST:PORT (QGroundControl listens on udp:127.0.0.1:14550)")
    })?;
    rest.to_socket_addrs()
        .map_err(|e| format!("--mavlink {spec:?}: {e}"))?
        .next()
        .ok_or_else(|| format!("--mavlink {spec:?}: {rest:?} names no address"))
}

impl MavUdp {
    /// An endpoint that sends to the ground control station at `spec` (`udp:HOST:PORT`).
    pub fn open(spec: &str) -> Result<Self, String> {
        let peer = parse_spec(spec)?;
        let bind = bind_address(&peer);
        let socket = UdpSocket::bind(bind).map_err(|e| format!("--mavlink {spec:?}: bind {bind}: {e}"))?;
        socket.set_nonblocking(true).map_err(|e| format!("--mavlink {spec:?}: {e}"))?;
        Ok(Self { socket, peer, sequence: 0, counters: UdpCounters::default() })
    }

    /// The address the endpoint listens on.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// What was counted.
    pub fn counters(&self) -> UdpCounters {
        self.counters
    }

    /// Sends each message in its own datagram (MAVLink 2, our system and component ids). A refused send is
    /// counted, not an error: the ground control station may come and go.
    pub fn send(&mut self, messages: &[MavMessage]) {
        for m in messages {
            let header = mavlink::MavHeader {
                system_id: u32::from(SYSTEM_ID),
                component_id: COMPONENT_ID,
                sequence: self.sequence,
            };
            self.sequence = self.sequence.wrapping_add(1);
            let mut buf = Vec::with_capacity(64);
            if mavlink::write_v2_msg(&mut buf, header, m).is_err() {
                self.counters.send_errors += 1;
                continue;
            }
            match self.socket.send_to(&buf, self.peer) {
                Ok(_) => self.counters.sent += 1,
                Err(_) => self.counters.send_errors += 1,
            }
        }
    }

    /// Every message the ground control station sent since the last call, with its system id (never
    /// blocks).
    pub fn receive(&mut self) -> std::io::Result<Vec<(u32, MavMessage)>> {
        let mut out = Vec::new();
        let mut buf = [0u8; 2048];
        loop {
            let (n, from) = match self.socket.recv_from(&mut buf) {
                Ok(x) => x,
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(out),
                // An earlier send to a closed port reported back (ICMP): counted with the sends.
                Err(e) if e.kind() == ErrorKind::ConnectionRefused => {
                    self.counters.send_errors += 1;
                    continue;
                }
                Err(e) => return Err(e),
            };
            if from != self.peer {
                self.counters.foreign += 1;
                continue;
            }
            self.counters.received += 1;
            parse_datagram(&buf[..n], &mut out, &mut self.counters);
        }
    }
}

/// The MAVLink messages (v1 or v2) one datagram holds; a datagram with none counts as unparsable (the
/// reader skips what fails its CRC or names a message the common dialect does not have).
fn parse_datagram(bytes: &[u8], out: &mut Vec<(u32, MavMessage)>, counters: &mut UdpCounters) {
    let mut reader = mavlink::MavlinkReader::new(bytes);
    let before = out.len();
    loop {
        match reader.read_any_message::<MavMessage>() {
            Ok((header, m)) => {
                counters.messages += 1;
                out.push((header.system_id, m));
            }
            Err(mavlink::error::MessageReadError::Io(e)) if e.kind() == ErrorKind::UnexpectedEof => break,
            Err(_) => {
                counters.unparsable += 1;
                return;
            }
        }
    }
    if out.len() == before {
        counters.unparsable += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mavlink_bridge::mav;

    #[test]
    fn binds_loopback_for_a_local_ground_control_station_and_parses_specs() {
        let local = parse_spec("udp:127.0.0.1:14550").unwrap();
        assert_eq!(local.port(), 14550);
        assert!(bind_address(&local).ip().is_loopback());
        assert!(bind_address(&"[::1]:14550".parse().unwrap()).ip().is_loopback());
        assert!(bind_address(&"192.168.1.20:14550".parse().unwrap()).ip().is_unspecified());
        let e = parse_spec("tcp:127.0.0.1:14550").unwrap_err();
        assert!(e.contains("udp:HOST:PORT"), "{e}");
        assert!(parse_spec("udp:127.0.0.1").is_err());
        let m = MavUdp::open("udp:127.0.0.1:14550").unwrap();
        assert!(m.local_addr().unwrap().ip().is_loopback());
    }

    #[test]
    fn round_trip_over_loopback_and_strangers_are_dropped() {
        let gcs = UdpSocket::bind("127.0.0.1:0").unwrap();
        let mut v = MavUdp::open(&format!("udp:{}", gcs.local_addr().unwrap())).unwrap();
        let hb = crate::mavlink_bridge::Bridge::new().heartbeat();
        v.send(&[hb.clone(), hb]);
        let mut buf = [0u8; 512];
        gcs.set_read_timeout(Some(std::time::Duration::from_secs(2))).unwrap();
        let (n, _) = gcs.recv_from(&mut buf).unwrap();
        let (h, m) = mavlink::MavlinkReader::new(&buf[..n]).read_any_message::<MavMessage>().unwrap();
        assert_eq!((h.system_id, h.component_id, h.sequence), (u32::from(SYSTEM_ID), COMPONENT_ID, 0));
        assert!(matches!(m, MavMessage::HEARTBEAT(_)));
        let (n, _) = gcs.recv_from(&mut buf).unwrap();
        let h = mavlink::MavlinkReader::new(&buf[..n]).read_any_message::<MavMessage>().unwrap().0;
        assert_eq!(h.sequence, 1);

        // The ground control station asks for the parameters; a stranger sends the same.
        let ask = MavMessage::PARAM_REQUEST_LIST(mav::PARAM_REQUEST_LIST_DATA {
            target_system: 1,
            target_component: 1,
        });
        let mut bytes = Vec::new();
        let header = mavlink::MavHeader { system_id: 255, component_id: 190, sequence: 7 };
        mavlink::write_v2_msg(&mut bytes, header, &ask).unwrap();
        let stranger = UdpSocket::bind("127.0.0.1:0").unwrap();
        stranger.send_to(&bytes, v.local_addr().unwrap()).unwrap();
        gcs.send_to(&bytes, v.local_addr().unwrap()).unwrap();
        // Garbage, and a message with a flipped payload byte (bad CRC).
        gcs.send_to(&[0xfd, 1, 2, 3], v.local_addr().unwrap()).unwrap();
        let mut bad = bytes.clone();
        bad[10] ^= 0x40;
        gcs.send_to(&bad, v.local_addr().unwrap()).unwrap();
        let mut got = Vec::new();
        for _ in 0..200 {
            got.extend(v.receive().unwrap());
            if v.counters().received + v.counters().foreign >= 4 {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        assert_eq!(got.len(), 1, "{got:?}");
        assert_eq!(got[0].0, 255);
        assert!(matches!(got[0].1, MavMessage::PARAM_REQUEST_LIST(_)));
        let c = v.counters();
        assert_eq!((c.sent, c.received, c.messages, c.foreign, c.unparsable), (2, 3, 1, 1, 2), "{c:?}");
    }
}
