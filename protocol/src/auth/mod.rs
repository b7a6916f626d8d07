//! Authenticated frames: only a station holding the vehicle's key may command it (docs/security.md).
//!
//! Every frame of a keyed link carries a 48-bit tag, HMAC-SHA256 truncated (RFC 2104, section 5), over its
//! direction, kind, counter and payload, in place of the CRC-16 of the unauthenticated frame:
//!
//! ```text
//! frame   = cobs(body) 0x00
//! body    = kind counter payload tag
//! kind    = the first byte, in place of the unauthenticated frame's version (1): 2 data (session key),
//!           3 station hello, 4 vehicle welcome (both with the long-term key)
//! counter = u32 varint; data frames: 1, 2, 3, ... per direction and session; 0 in the handshake
//! payload = postcard message (data), the station's nonce (hello), both nonces (welcome)
//! tag     = first 6 bytes of HMAC-SHA256(key, "WLQA" direction kind counter payload)
//! ```
//!
//! A session starts with a handshake: the station sends a hello with a fresh random nonce, the vehicle
//! answers with the station's nonce and its own fresh one, and both derive the session key
//! `HMAC-SHA256(K, "WLQ session" station_nonce vehicle_nonce)`. Data frames are tagged with the session key and
//! their counter must increase strictly, so a frame replayed, reordered or taken from another session (before
//! a reboot of either side, whose new nonce makes a new key) fails. Every refused frame is counted by reason
//! ([`AuthCounters`]) and never acted on.
//!
//! The algorithms never read a clock or a random source: the caller passes the time and the nonces.
use hmac::{Hmac, KeyInit, Mac};
use serde::{Serialize, de::DeserializeOwned};
use sha2::Sha256;

use crate::frame::{EncodeError, MAX_FRAME, WIRE_VERSION, cobs_encode};

pub mod provision;

/// First byte of an authenticated data frame (the hello is 3, the welcome 4; an unauthenticated frame's is its
/// wire version, 1).
pub const AUTH_WIRE_VERSION: u8 = 2;
/// Length of the tag (bytes): 48 bits, as MAVLink 2's signature (docs/security.md weighs it against the link
/// budget).
pub const TAG_LEN: usize = 6;
/// Length of the long-term and the session keys (bytes).
pub const KEY_LEN: usize = 32;
/// Length of each side's handshake nonce (bytes).
pub const NONCE_LEN: usize = 16;
/// How long a session's receiving side must have been quiet (no authentic data frame) before a new hello may
/// replace it while the vehicle is armed (us): a replayed hello cannot cut a live link.
pub const HELLO_QUIET_US: u64 = 2_000_000;

const KIND_DATA: u8 = AUTH_WIRE_VERSION;
const KIND_HELLO: u8 = AUTH_WIRE_VERSION + 1;
const KIND_WELCOME: u8 = AUTH_WIRE_VERSION + 2;
const DOMAIN: &[u8; 4] = b"WLQA";

/// A shared key.
pub type Key = [u8; KEY_LEN];
/// A handshake nonce.
pub type Nonce = [u8; NONCE_LEN];

/// Which side of the link this is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Role {
    /// The ground station: sends the uplink.
    Station,
    /// The vehicle: sends the downlink.
    Vehicle,
}

impl Role {
    /// The direction byte of the frames this side sends.
    fn sends(self) -> u8 {
        match self {
            Role::Station => b'U',
            Role::Vehicle => b'D',
        }
    }

    fn receives(self) -> u8 {
        match self {
            Role::Station => b'D',
            Role::Vehicle => b'U',
        }
    }
}

/// Why a frame was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AuthError {
    /// Too short for a version, a kind, a counter and a tag.
    Truncated,
    /// An unauthenticated frame (wire version 1) on a keyed link: a downgrade.
    Downgrade,
    /// Another version byte.
    UnknownVersion,
    /// The tag does not match: forged, corrupted, or under another key or session.
    BadTag,
    /// A data frame whose counter is not above the last accepted one: replayed or reordered.
    Replayed,
    /// A data frame before any session, or a handshake frame this side does not take (a welcome that does not
    /// answer this station's hello, a hello to a station).
    NoSession,
    /// A valid hello while the vehicle is armed and its session alive: a replay cannot cut the link.
    HelloRefused,
    /// Authentic, but the payload does not decode as a message.
    Malformed,
}

/// Frames refused by reason, and those accepted.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, postcard_schema::Schema,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AuthCounters {
    /// Data frames accepted.
    pub ok: u32,
    /// Sessions started (handshakes completed on this side).
    pub sessions: u32,
    /// [`AuthError::Truncated`].
    pub truncated: u32,
    /// [`AuthError::Downgrade`].
    pub downgrade: u32,
    /// [`AuthError::UnknownVersion`].
    pub unknown_version: u32,
    /// [`AuthError::BadTag`].
    pub bad_tag: u32,
    /// [`AuthError::Replayed`].
    pub replayed: u32,
    /// [`AuthError::NoSession`].
    pub no_session: u32,
    /// [`AuthError::HelloRefused`].
    pub hello_refused: u32,
    /// [`AuthError::Malformed`].
    pub malformed: u32,
}

impl AuthCounters {
    /// Frames refused, all reasons.
    pub fn refused(&self) -> u32 {
        self.truncated
            + self.downgrade
            + self.unknown_version
            + self.bad_tag
            + self.replayed
            + self.no_session
            + self.hello_refused
            + self.malformed
    }

    fn count(&mut self, e: AuthError) {
        let c = match e {
            AuthError::Truncated => &mut self.truncated,
            AuthError::Downgrade => &mut self.downgrade,
            AuthError::UnknownVersion => &mut self.unknown_version,
            AuthError::BadTag => &mut self.bad_tag,
            AuthError::Replayed => &mut self.replayed,
            AuthError::NoSession => &mut self.no_session,
            AuthError::HelloRefused => &mut self.hello_refused,
            AuthError::Malformed => &mut self.malformed,
        };
        *c = c.saturating_add(1);
    }
}

/// What an accepted frame was.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Opened<T> {
    /// A message of the session.
    Message(T),
    /// A handshake completed: on the vehicle, answer with [`SecureLink::welcome`]; on the station, the
    /// session is up.
    SessionStarted,
}

/// Why a frame could not be sealed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SealError {
    /// No session yet (the station sends a hello first; the vehicle waits for one).
    NoSession,
    /// The session's counter is spent (2^32 - 1 frames): start a new session.
    CounterSpent,
    /// The output buffer is too small, or the frame longer than [`MAX_FRAME`].
    BufferFull,
}

impl From<EncodeError> for SealError {
    fn from(_: EncodeError) -> Self {
        SealError::BufferFull
    }
}

/// HMAC-SHA256 under one key, its padded key blocks already hashed (RFC 2104): each tag then costs the
/// message's blocks and two finishing blocks, not two more for the key (a third of a telemetry frame's cost on
/// the Cortex-M4, docs/security.md).
type KeyedMac = Hmac<Sha256>;

fn keyed(key: &Key) -> KeyedMac {
    // A key shorter than SHA-256's 64-byte block is zero-padded to it (RFC 2104, section 2): the padded block
    // is the same key, taken by the infallible constructor.
    let mut block = hmac::digest::Key::<KeyedMac>::default();
    block[..KEY_LEN].copy_from_slice(key);
    <KeyedMac as KeyInit>::new(&block)
}

#[derive(Clone)]
struct Session {
    mac: KeyedMac,
    sent: u32,
    received: u32,
}

impl Session {
    fn new(long_term: &Key, station_nonce: &Nonce, vehicle_nonce: &Nonce) -> Self {
        Self { mac: keyed(&session_key(long_term, station_nonce, vehicle_nonce)), sent: 0, received: 0 }
    }
}

/// One side of a keyed link: seals what it sends, opens what it receives.
pub struct SecureLink {
    role: Role,
    key: Key,
    key_mac: KeyedMac,
    session: Option<Session>,
    /// Station: the nonce of the hello it sent. Vehicle: the nonces of the last hello it took, for the welcome.
    station_nonce: Option<Nonce>,
    vehicle_nonce: Option<Nonce>,
    last_authentic_us: u64,
    counters: AuthCounters,
}

fn mac(keyed: &KeyedMac, parts: &[&[u8]]) -> [u8; 32] {
    let mut m = keyed.clone();
    for p in parts {
        m.update(p);
    }
    m.finalize().into_bytes().into()
}

/// The session key both sides derive from the long-term key and the two nonces.
pub fn session_key(key: &Key, station_nonce: &Nonce, vehicle_nonce: &Nonce) -> Key {
    mac(&keyed(key), &[b"WLQ session", station_nonce, vehicle_nonce])
}

fn varint_u32(mut v: u32, out: &mut [u8; 5]) -> usize {
    let mut n = 0;
    loop {
        let b = (v & 0x7F) as u8;
        v >>= 7;
        if v == 0 {
            out[n] = b;
            return n + 1;
        }
        out[n] = b | 0x80;
        n += 1;
    }
}

/// Reads a u32 varint at the start of `b`: the value and its length.
fn read_varint_u32(b: &[u8]) -> Option<(u32, usize)> {
    let mut v: u32 = 0;
    for (i, &byte) in b.iter().enumerate().take(5) {
        let part = u32::from(byte & 0x7F);
        if i == 4 && part > 0x0F {
            return None;
        }
        v |= part << (7 * i);
        if byte & 0x80 == 0 {
            // Only the shortest form, so that one counter has one encoding.
            if i > 0 && byte == 0 {
                return None;
            }
            return Some((v, i + 1));
        }
    }
    None
}

fn tag(key: &KeyedMac, direction: u8, kind: u8, counter: &[u8], payload: &[u8]) -> [u8; 32] {
    mac(key, &[DOMAIN, &[direction, kind], counter, payload])
}

/// Seals one body (`kind counter payload tag`) and frames it (COBS and the delimiter) into `out`.
fn seal_body<'a>(
    key: &KeyedMac,
    direction: u8,
    kind: u8,
    counter: u32,
    payload: &[u8],
    out: &'a mut [u8],
) -> Result<&'a [u8], SealError> {
    let mut raw = [0u8; MAX_FRAME];
    let mut c = [0u8; 5];
    let cn = varint_u32(counter, &mut c);
    let n = 1 + cn + payload.len() + TAG_LEN;
    if n > MAX_FRAME - 4 {
        return Err(SealError::BufferFull);
    }
    raw[0] = kind;
    raw[1..1 + cn].copy_from_slice(&c[..cn]);
    raw[1 + cn..1 + cn + payload.len()].copy_from_slice(payload);
    let t = tag(key, direction, kind, &c[..cn], payload);
    raw[n - TAG_LEN..n].copy_from_slice(&t[..TAG_LEN]);
    let len = cobs_encode(&raw[..n], out)?;
    if len + 1 > MAX_FRAME {
        return Err(SealError::BufferFull);
    }
    *out.get_mut(len).ok_or(SealError::BufferFull)? = 0;
    Ok(&out[..len + 1])
}

impl SecureLink {
    /// One side of a link keyed with `key`, before any session.
    pub fn new(role: Role, key: Key) -> Self {
        Self {
            role,
            key,
            key_mac: keyed(&key),
            session: None,
            station_nonce: None,
            vehicle_nonce: None,
            last_authentic_us: 0,
            counters: AuthCounters {
                ok: 0,
                sessions: 0,
                truncated: 0,
                downgrade: 0,
                unknown_version: 0,
                bad_tag: 0,
                replayed: 0,
                no_session: 0,
                hello_refused: 0,
                malformed: 0,
            },
        }
    }

    /// The counters.
    pub fn counters(&self) -> AuthCounters {
        self.counters
    }

    /// Whether a session is up.
    pub fn has_session(&self) -> bool {
        self.session.is_some()
    }

    /// Station: the hello that starts a session, with a fresh random `nonce` (never reuse one). Any earlier
    /// session ends.
    pub fn hello<'a>(&mut self, nonce: Nonce, out: &'a mut [u8]) -> Result<&'a [u8], SealError> {
        self.session = None;
        self.station_nonce = Some(nonce);
        seal_body(&self.key_mac, self.role.sends(), KIND_HELLO, 0, &nonce, out)
    }

    /// Vehicle: the welcome that answers the hello just taken ([`Opened::SessionStarted`]).
    pub fn welcome<'a>(&mut self, out: &'a mut [u8]) -> Result<&'a [u8], SealError> {
        let (Some(s), Some(v)) = (self.station_nonce, self.vehicle_nonce) else {
            return Err(SealError::NoSession);
        };
        let mut payload = [0u8; 2 * NONCE_LEN];
        payload[..NONCE_LEN].copy_from_slice(&s);
        payload[NONCE_LEN..].copy_from_slice(&v);
        seal_body(&self.key_mac, self.role.sends(), KIND_WELCOME, 0, &payload, out)
    }

    /// Seals a message of the session as a complete frame into `out`.
    pub fn seal<'a, T: Serialize>(&mut self, msg: &T, out: &'a mut [u8]) -> Result<&'a [u8], SealError> {
        let Some(s) = self.session.as_mut() else {
            return Err(SealError::NoSession);
        };
        let counter = s.sent.checked_add(1).ok_or(SealError::CounterSpent)?;
        let mut payload = [0u8; MAX_FRAME];
        let p = postcard::to_slice(msg, &mut payload).map_err(|_| SealError::BufferFull)?;
        let frame = seal_body(&s.mac, self.role.sends(), KIND_DATA, counter, p, out)?;
        s.sent = counter;
        Ok(frame)
    }

    /// Opens one frame's body (COBS already undone: [`crate::frame::Decoder::push_body`]) received at
    /// `now_us`. On the vehicle, `armed` says whether a hello may only replace a session that has been quiet
    /// for [`HELLO_QUIET_US`], and `vehicle_nonce` gives the fresh nonce of a new session (called only when a
    /// hello is taken). Refusals are counted.
    pub fn open<T: DeserializeOwned>(
        &mut self,
        body: &[u8],
        now_us: u64,
        armed: bool,
        vehicle_nonce: impl FnOnce() -> Nonce,
    ) -> Result<Opened<T>, AuthError> {
        let r = self.open_inner(body, now_us, armed, vehicle_nonce);
        match &r {
            Ok(Opened::Message(_)) => self.counters.ok = self.counters.ok.saturating_add(1),
            Ok(Opened::SessionStarted) => self.counters.sessions = self.counters.sessions.saturating_add(1),
            Err(e) => self.counters.count(*e),
        }
        r
    }

    fn open_inner<T: DeserializeOwned>(
        &mut self,
        body: &[u8],
        now_us: u64,
        armed: bool,
        vehicle_nonce: impl FnOnce() -> Nonce,
    ) -> Result<Opened<T>, AuthError> {
        let kind = match body.first() {
            None => return Err(AuthError::Truncated),
            Some(&WIRE_VERSION) => return Err(AuthError::Downgrade),
            Some(&k) if (KIND_DATA..=KIND_WELCOME).contains(&k) => k,
            Some(_) => return Err(AuthError::UnknownVersion),
        };
        if body.len() < 2 + TAG_LEN {
            return Err(AuthError::Truncated);
        }
        let (counter, cn) = read_varint_u32(&body[1..]).ok_or(AuthError::Truncated)?;
        if body.len() < 1 + cn + TAG_LEN {
            return Err(AuthError::Truncated);
        }
        let payload = &body[1 + cn..body.len() - TAG_LEN];
        let got = &body[body.len() - TAG_LEN..];
        let direction = self.role.receives();
        let check = |key: &KeyedMac| -> Result<(), AuthError> {
            let mut m = key.clone();
            m.update(DOMAIN);
            m.update(&[direction, kind]);
            m.update(&body[1..1 + cn]);
            m.update(payload);
            m.verify_truncated_left(got).map_err(|_| AuthError::BadTag)
        };
        match kind {
            KIND_DATA => {
                let Some(s) = self.session.as_ref() else {
                    return Err(AuthError::NoSession);
                };
                check(&s.mac)?;
                if counter <= s.received {
                    return Err(AuthError::Replayed);
                }
                let msg = match postcard::take_from_bytes::<T>(payload) {
                    Ok((m, [])) => m,
                    _ => return Err(AuthError::Malformed),
                };
                if let Some(s) = self.session.as_mut() {
                    s.received = counter;
                }
                self.last_authentic_us = now_us;
                Ok(Opened::Message(msg))
            }
            KIND_HELLO if self.role == Role::Vehicle => {
                check(&self.key_mac)?;
                let station: Nonce = payload.try_into().map_err(|_| AuthError::Malformed)?;
                let quiet = now_us.saturating_sub(self.last_authentic_us) >= HELLO_QUIET_US;
                if armed && self.session.is_some() && !quiet {
                    return Err(AuthError::HelloRefused);
                }
                let vehicle = vehicle_nonce();
                self.station_nonce = Some(station);
                self.vehicle_nonce = Some(vehicle);
                self.session = Some(Session::new(&self.key, &station, &vehicle));
                self.last_authentic_us = now_us;
                Ok(Opened::SessionStarted)
            }
            KIND_WELCOME if self.role == Role::Station => {
                check(&self.key_mac)?;
                if payload.len() != 2 * NONCE_LEN {
                    return Err(AuthError::Malformed);
                }
                let (s, v) = payload.split_at(NONCE_LEN);
                let Some(mine) = self.station_nonce else {
                    return Err(AuthError::NoSession);
                };
                if s != mine || self.session.is_some() {
                    // An answer to another hello (an old one replayed), or a second answer to this one.
                    return Err(AuthError::NoSession);
                }
                let vehicle: Nonce = v.try_into().map_err(|_| AuthError::Malformed)?;
                self.session = Some(Session::new(&self.key, &mine, &vehicle));
                self.last_authentic_us = now_us;
                Ok(Opened::SessionStarted)
            }
            _ => Err(AuthError::NoSession),
        }
    }
}

#[cfg(test)]
mod tests;
