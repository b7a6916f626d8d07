//! The vehicle's end of the radio link: the bytes the radio delivered, decoded and authenticated into uplink
//! messages; the downlink sealed into frames; the arming gate of the development mode (docs/security.md).
//!
//! One code for the firmware and the simulator's virtual vehicle. It never reads a clock or a random source:
//! the caller passes the time and, when a handshake needs one, a fresh nonce (the board's hardware RNG).
//!
//! - **Keyed** (a key provisioned, `protocol::auth::provision`): every frame is authenticated
//!   (`protocol::auth::SecureLink`); nothing goes down before a station's hello started a session, and what
//!   fails is dropped and counted by reason.
//! - **Development** (no key): unauthenticated frames (anyone on the radio may command the vehicle); an
//!   `Arm` command is refused ([`control_core::Refusal::Unauthenticated`], acknowledged and counted) unless the
//!   firmware was built with the `unauthenticated-link` feature ([`Security::Development`]'s `allow_arming`);
//!   so is a configuration upload (`ConfigRefusal::Unauthenticated`), which changes what the vehicle flies.
//!
//! [`VehicleRadio::status_due`] gives, once a second, the [`LinkStatus`] the vehicle sends down: the mode and
//! the counters, which the station shows and logs.
use control_core::{Command, CommandResult, Refusal};
use protocol::auth::{AuthCounters, Key, Nonce, Opened, Role, SealError, SecureLink};
use protocol::frame::{DecodeCounters, Decoder, MAX_FRAME, encode};
use protocol::{ConfigAck, ConfigOutcome, ConfigRefusal, Downlink, LinkStatus, Uplink};

/// How often the vehicle reports its link's state ([`Downlink::LinkStatus`], us).
pub const STATUS_PERIOD_US: u64 = 1_000_000;

/// How the link is secured.
#[derive(Clone, Copy)]
pub enum Security {
    /// Authenticated with this key.
    Keyed(Key),
    /// Unauthenticated: the development mode. `allow_arming` only in a firmware built with the
    /// `unauthenticated-link` feature.
    Development {
        /// Whether an `Arm` command is carried out (and a configuration upload taken).
        allow_arming: bool,
    },
}

/// What one received byte completed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Incoming {
    /// A message for the flight stack.
    Message(Uplink),
    /// A frame to send back at once: the welcome that completes a handshake, or the refusal of an `Arm` in
    /// the development mode. Its bytes are the first `.0` of the reply buffer passed to [`VehicleRadio::push`].
    Reply(usize),
    /// A frame dropped (counted by the framing or the authentication).
    Refused,
}

/// Why a downlink message was not framed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NotSent {
    /// Keyed, and no station has started a session yet.
    NoSession,
    /// The message does not fit a frame, or the session's counter is spent.
    Unframable,
}

/// The vehicle's end of the radio link.
pub struct VehicleRadio {
    decoder: Decoder,
    link: Option<SecureLink>,
    allow_arming: bool,
    arm_refused: u32,
    config_refused: u32,
    not_sent: [u32; 2],
    next_status_us: u64,
}

impl VehicleRadio {
    /// A radio secured as `security` says.
    pub fn new(security: Security) -> Self {
        let (link, allow_arming) = match security {
            Security::Keyed(k) => (Some(SecureLink::new(Role::Vehicle, k)), true),
            Security::Development { allow_arming } => (None, allow_arming),
        };
        Self {
            decoder: Decoder::new(),
            link,
            allow_arming,
            arm_refused: 0,
            config_refused: 0,
            not_sent: [0; 2],
            next_status_us: 0,
        }
    }

    /// Whether frames are authenticated.
    pub fn authenticated(&self) -> bool {
        self.link.is_some()
    }

    /// What a status line says: `hmac-sha256-48`, or the development mode and whether it arms.
    pub fn describe(&self) -> &'static str {
        match (self.link.is_some(), self.allow_arming) {
            (true, _) => "hmac-sha256-48",
            (false, true) => "none (development, arming allowed)",
            (false, false) => "none (development, arming refused)",
        }
    }

    /// Feeds one byte received at `now_us`. `armed` and `nonce` as `SecureLink::open` takes them (`nonce` is
    /// called only when a hello starts a session). A reply goes into `reply`.
    pub fn push(
        &mut self,
        byte: u8,
        now_us: u64,
        armed: bool,
        nonce: impl FnOnce() -> Nonce,
        reply: &mut [u8; MAX_FRAME],
    ) -> Option<Incoming> {
        let msg = match self.link.as_mut() {
            None => match self.decoder.push::<Uplink>(byte)? {
                Ok(m) => m,
                Err(_) => return Some(Incoming::Refused),
            },
            Some(link) => {
                let body = match self.decoder.push_body(byte)? {
                    Ok(b) => b,
                    Err(_) => return Some(Incoming::Refused),
                };
                match link.open::<Uplink>(body, now_us, armed, nonce) {
                    Ok(Opened::Message(m)) => m,
                    Ok(Opened::SessionStarted) => {
                        return Some(match link.welcome(reply) {
                            Ok(w) => Incoming::Reply(w.len()),
                            Err(_) => Incoming::Refused,
                        });
                    }
                    Err(_) => return Some(Incoming::Refused),
                }
            }
        };
        if msg == Uplink::Command(Command::Arm) && !self.allow_arming {
            self.arm_refused = self.arm_refused.saturating_add(1);
            let ack = Downlink::CommandAck(CommandResult::Refused(Command::Arm, Refusal::Unauthenticated));
            return Some(match encode(&ack, reply) {
                Ok(f) => Incoming::Reply(f.len()),
                Err(_) => Incoming::Refused,
            });
        }
        // A configuration upload changes what the vehicle flies, as an `Arm` starts it: refused alike. The
        // first piece of each try is answered (the station sends the whole upload again when it hears nothing).
        if let Uplink::Config(c) = msg
            && !self.allow_arming
        {
            self.config_refused = self.config_refused.saturating_add(1);
            if c.offset != 0 {
                return Some(Incoming::Refused);
            }
            let ack = Downlink::ConfigAck(ConfigAck {
                crc32: c.crc32,
                outcome: ConfigOutcome::Refused(ConfigRefusal::Unauthenticated),
            });
            return Some(match encode(&ack, reply) {
                Ok(f) => Incoming::Reply(f.len()),
                Err(_) => Incoming::Refused,
            });
        }
        Some(Incoming::Message(msg))
    }

    /// Frames a downlink message into `out`: sealed when keyed (not before a session), plain otherwise.
    /// What is not framed is counted ([`VehicleRadio::not_sent`]).
    pub fn frame<'a>(&mut self, msg: &Downlink, out: &'a mut [u8; MAX_FRAME]) -> Result<&'a [u8], NotSent> {
        let r = match self.link.as_mut() {
            Some(l) => l.seal(msg, out).map_err(|e| match e {
                SealError::NoSession => NotSent::NoSession,
                SealError::CounterSpent | SealError::BufferFull => NotSent::Unframable,
            }),
            None => encode(msg, out).map_err(|_| NotSent::Unframable),
        };
        if let Err(e) = r {
            let c = &mut self.not_sent[e as usize];
            *c = c.saturating_add(1);
        }
        r
    }

    /// Downlink messages not framed: before a session, and unframable.
    pub fn not_sent(&self) -> [u32; 2] {
        self.not_sent
    }

    /// Whether messages can go down now (always in the development mode; after a handshake when keyed).
    pub fn ready(&self) -> bool {
        self.link.as_ref().is_none_or(|l| l.has_session())
    }

    /// The authentication's counters (zero in the development mode).
    pub fn auth_counters(&self) -> AuthCounters {
        self.link.as_ref().map_or_else(AuthCounters::default, |l| l.counters())
    }

    /// The framing's counters.
    pub fn framing(&self) -> DecodeCounters {
        self.decoder.counters()
    }

    /// Configuration pieces refused because the link is not authenticated (development mode, a firmware built
    /// without `unauthenticated-link`).
    pub fn config_refused(&self) -> u32 {
        self.config_refused
    }

    /// The link's state now.
    pub fn status(&self) -> LinkStatus {
        LinkStatus {
            authenticated: self.authenticated(),
            arm_refused: self.arm_refused,
            framing_errors: self.decoder.counters().errors(),
            auth: self.auth_counters(),
        }
    }

    /// The [`Downlink::LinkStatus`] to send at `now_us`, once per [`STATUS_PERIOD_US`] (the first at once).
    pub fn status_due(&mut self, now_us: u64) -> Option<Downlink> {
        if now_us < self.next_status_us {
            return None;
        }
        self.next_status_us = now_us + STATUS_PERIOD_US;
        Some(Downlink::LinkStatus(self.status()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::frame::cobs_decode_in_place;

    const K: Key = [0x42; 32];

    fn feed(r: &mut VehicleRadio, bytes: &[u8], now_us: u64, reply: &mut [u8; MAX_FRAME]) -> Vec<Incoming> {
        let mut out = Vec::new();
        for &b in bytes {
            if let Some(i) = r.push(b, now_us, false, || [7; 16], reply) {
                out.push(i);
            }
        }
        out
    }

    fn ack_in(reply: &[u8]) -> Downlink {
        let mut body = reply[..reply.len() - 1].to_vec();
        let n = cobs_decode_in_place(&mut body).unwrap();
        assert_eq!(body[0], protocol::frame::WIRE_VERSION);
        postcard::from_bytes(&body[1..n - 2]).unwrap()
    }

    #[test]
    fn the_development_mode_refuses_to_arm_unless_built_to_allow_it() {
        let mut buf = [0u8; MAX_FRAME];
        let arm = encode(&Uplink::Command(Command::Arm), &mut buf).unwrap().to_vec();
        let beat = encode(&Uplink::Heartbeat, &mut buf).unwrap().to_vec();
        let mut reply = [0u8; MAX_FRAME];

        let mut r = VehicleRadio::new(Security::Development { allow_arming: false });
        assert!(!r.authenticated());
        assert_eq!(r.describe(), "none (development, arming refused)");
        // Other messages pass; the Arm does not reach the flight stack and is answered.
        assert_eq!(feed(&mut r, &beat, 0, &mut reply), [Incoming::Message(Uplink::Heartbeat)]);
        let got = feed(&mut r, &arm, 0, &mut reply);
        let [Incoming::Reply(n)] = got[..] else { panic!("{got:?}") };
        assert_eq!(
            ack_in(&reply[..n]),
            Downlink::CommandAck(CommandResult::Refused(Command::Arm, Refusal::Unauthenticated))
        );
        assert_eq!(r.status().arm_refused, 1);
        assert!(!r.status().authenticated);
        // The framing counted both frames; a damaged one is counted as such and goes no further.
        assert_eq!((r.framing().ok, r.framing().errors()), (2, 0));
        let mut damaged = beat.clone();
        damaged[2] ^= 0x10;
        assert_eq!(feed(&mut r, &damaged, 0, &mut reply), [Incoming::Refused]);
        assert_eq!((r.framing().ok, r.framing().errors()), (2, 1));

        let mut allowed = VehicleRadio::new(Security::Development { allow_arming: true });
        assert_eq!(
            feed(&mut allowed, &arm, 0, &mut reply),
            [Incoming::Message(Uplink::Command(Command::Arm))]
        );
        assert_eq!(allowed.status().arm_refused, 0);
        // Unauthenticated downlink frames go at once.
        assert!(allowed.ready());
        assert!(allowed.frame(&Downlink::LinkStatus(allowed.status()), &mut buf).is_ok());
    }

    #[test]
    fn the_development_mode_refuses_configuration_uploads_unless_built_to_allow_them() {
        let cfg = crate::FlightConfig::paper();
        let (crc32, pieces) = crate::config_upload::chunks(&cfg).unwrap();
        let mut buf = [0u8; MAX_FRAME];
        let mut reply = [0u8; MAX_FRAME];
        let frames: Vec<Vec<u8>> =
            pieces.iter().map(|p| encode(&Uplink::Config(*p), &mut buf).unwrap().to_vec()).collect();
        let mut r = VehicleRadio::new(Security::Development { allow_arming: false });
        // The first piece is answered with the refusal; the others are dropped and counted.
        let got = feed(&mut r, &frames[0], 0, &mut reply);
        let [Incoming::Reply(n)] = got[..] else { panic!("{got:?}") };
        assert_eq!(
            ack_in(&reply[..n]),
            Downlink::ConfigAck(ConfigAck {
                crc32,
                outcome: ConfigOutcome::Refused(ConfigRefusal::Unauthenticated)
            })
        );
        for f in &frames[1..] {
            assert_eq!(feed(&mut r, f, 0, &mut reply), [Incoming::Refused]);
        }
        assert_eq!(r.config_refused() as usize, frames.len());
        assert_eq!(r.status().arm_refused, 0, "not counted as an Arm");
        // Built to allow it, the pieces pass to the caller's assembler.
        let mut allowed = VehicleRadio::new(Security::Development { allow_arming: true });
        for (f, p) in frames.iter().zip(&pieces) {
            assert_eq!(feed(&mut allowed, f, 0, &mut reply), [Incoming::Message(Uplink::Config(*p))]);
        }
        assert_eq!(allowed.config_refused(), 0);
    }

    #[test]
    fn keyed_the_radio_takes_only_its_station_s_frames_and_arms_on_them() {
        let mut station = SecureLink::new(Role::Station, K);
        let mut r = VehicleRadio::new(Security::Keyed(K));
        assert!(r.authenticated() && !r.ready());
        let mut reply = [0u8; MAX_FRAME];
        let mut buf = [0u8; MAX_FRAME];
        // Nothing goes down before a session: refused and counted.
        assert_eq!(r.frame(&Downlink::LinkStatus(r.status()), &mut buf), Err(NotSent::NoSession));
        assert_eq!(r.not_sent(), [1, 0]);
        // An unauthenticated Arm (a downgrade) does nothing.
        let plain = encode(&Uplink::Command(Command::Arm), &mut buf).unwrap().to_vec();
        assert_eq!(feed(&mut r, &plain, 0, &mut reply), [Incoming::Refused]);
        assert_eq!(r.auth_counters().downgrade, 1);
        // The handshake: the reply is the welcome, which the station takes.
        let hello = station.hello([1; 16], &mut buf).unwrap().to_vec();
        let got = feed(&mut r, &hello, 10, &mut reply);
        let [Incoming::Reply(n)] = got[..] else { panic!("{got:?}") };
        let mut body = reply[..n - 1].to_vec();
        let m = cobs_decode_in_place(&mut body).unwrap();
        assert_eq!(station.open::<Downlink>(&body[..m], 10, false, || [0; 16]), Ok(Opened::SessionStarted));
        assert!(r.ready());
        // A sealed Arm arms (a keyed link needs no feature).
        let arm = station.seal(&Uplink::Command(Command::Arm), &mut buf).unwrap().to_vec();
        assert_eq!(feed(&mut r, &arm, 20, &mut reply), [Incoming::Message(Uplink::Command(Command::Arm))]);
        // Replayed: refused.
        assert_eq!(feed(&mut r, &arm, 30, &mut reply), [Incoming::Refused]);
        let s = r.status();
        assert!(s.authenticated);
        assert_eq!((s.auth.ok, s.auth.replayed, s.auth.downgrade, s.auth.sessions), (1, 1, 1, 1));
        // The status goes down sealed, and the station reads it.
        let f = r.frame(&Downlink::LinkStatus(s), &mut buf).unwrap().to_vec();
        let mut body = f[..f.len() - 1].to_vec();
        let m = cobs_decode_in_place(&mut body).unwrap();
        assert_eq!(
            station.open::<Downlink>(&body[..m], 40, false, || [0; 16]),
            Ok(Opened::Message(Downlink::LinkStatus(s)))
        );
    }

    #[test]
    fn the_status_is_due_once_a_second() {
        let mut r = VehicleRadio::new(Security::Development { allow_arming: false });
        assert!(r.status_due(0).is_some());
        assert!(r.status_due(STATUS_PERIOD_US - 1).is_none());
        assert!(r.status_due(STATUS_PERIOD_US).is_some());
        assert!(r.status_due(STATUS_PERIOD_US + 10).is_none());
        assert!(r.status_due(5 * STATUS_PERIOD_US).is_some());
    }
}
