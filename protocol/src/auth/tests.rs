//! Attacks on the keyed link, each on its own: none may deliver a message, and each is counted.
use super::*;
use crate::frame::{Decoder, encode};
use crate::{Downlink, Uplink};
use control_core::{Command, CommandResult};

const K: Key = [7; KEY_LEN];
const OTHER: Key = [8; KEY_LEN];
const T0: u64 = 1_000_000;

fn nonce(b: u8) -> Nonce {
    [b; NONCE_LEN]
}

/// The bodies of the frames in `bytes` (COBS undone), as the receiving side's decoder gives them.
fn bodies(bytes: &[u8]) -> Vec<Vec<u8>> {
    let mut d = Decoder::new();
    bytes.iter().filter_map(|&b| d.push_body(b).map(|r| r.unwrap().to_vec())).collect()
}

fn body(frame: &[u8]) -> Vec<u8> {
    let b = bodies(frame);
    assert_eq!(b.len(), 1);
    b.into_iter().next().unwrap()
}

/// A station and a vehicle with a session (hello with nonce 1, welcome with nonce 2).
fn pair(key: Key) -> (SecureLink, SecureLink) {
    let (mut st, mut v) = (SecureLink::new(Role::Station, key), SecureLink::new(Role::Vehicle, key));
    let mut out = [0u8; MAX_FRAME];
    let hello = body(st.hello(nonce(1), &mut out).unwrap());
    assert_eq!(v.open::<Uplink>(&hello, T0, false, || nonce(2)), Ok(Opened::SessionStarted));
    let welcome = body(v.welcome(&mut out).unwrap());
    assert_eq!(st.open::<Downlink>(&welcome, T0, false, || unreachable!()), Ok(Opened::SessionStarted));
    (st, v)
}

fn seal<T: Serialize>(link: &mut SecureLink, m: &T) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    body(link.seal(m, &mut out).unwrap())
}

fn open_up(v: &mut SecureLink, b: &[u8]) -> Result<Opened<Uplink>, AuthError> {
    v.open::<Uplink>(b, T0 + 10, true, || nonce(9))
}

#[test]
fn a_session_carries_messages_both_ways_and_counts_them() {
    let (mut st, mut v) = pair(K);
    for c in [Command::Arm, Command::TakeOff, Command::Land] {
        let b = seal(&mut st, &Uplink::Command(c));
        assert_eq!(open_up(&mut v, &b), Ok(Opened::Message(Uplink::Command(c))));
    }
    let ack = Downlink::CommandAck(CommandResult::Accepted(Command::Arm));
    let b = seal(&mut v, &ack);
    assert_eq!(st.open::<Downlink>(&b, T0, false, || nonce(0)), Ok(Opened::Message(ack)));
    assert_eq!((v.counters().ok, v.counters().sessions, v.counters().refused()), (3, 1, 0));
    assert_eq!((st.counters().ok, st.counters().sessions), (1, 1));
    // The tag replaces the CRC and the kind the version byte: a frame costs its counter (1 byte up to 127,
    // 3 bytes up to 2^21) and the 6-byte tag, less the 2-byte CRC, more than unauthenticated.
    let mut out = [0u8; MAX_FRAME];
    let plain = encode(&Uplink::Heartbeat, &mut out).unwrap().len();
    let mut out2 = [0u8; MAX_FRAME];
    let sealed = st.seal(&Uplink::Heartbeat, &mut out2).unwrap().len();
    assert_eq!(sealed, plain + 1 + 6 - 2, "kind counter(1) payload tag(6) vs version payload crc(2)");
}

#[test]
fn forged_and_wrongly_keyed_commands_are_refused() {
    let (_, mut v) = pair(K);
    // A station with another key, in a session of its own.
    let (mut mallory, _) = pair(OTHER);
    let b = seal(&mut mallory, &Uplink::Command(Command::Arm));
    assert_eq!(open_up(&mut v, &b), Err(AuthError::BadTag));
    // A hand-made frame with a guessed tag.
    let mut forged = vec![AUTH_WIRE_VERSION, 1];
    let mut p = [0u8; 16];
    forged.extend_from_slice(postcard::to_slice(&Uplink::Command(Command::Arm), &mut p).unwrap());
    forged.extend([0xA5; TAG_LEN]);
    assert_eq!(open_up(&mut v, &forged), Err(AuthError::BadTag));
    // A hello under another key: no session with the forger.
    let mut out = [0u8; MAX_FRAME];
    let h = body(SecureLink::new(Role::Station, OTHER).hello(nonce(3), &mut out).unwrap());
    assert_eq!(v.open::<Uplink>(&h, T0, false, || nonce(4)), Err(AuthError::BadTag));
    assert_eq!((v.counters().ok, v.counters().bad_tag), (0, 3));
}

#[test]
fn a_replayed_or_reordered_command_is_refused() {
    let (mut st, mut v) = pair(K);
    let (a, b, c) = (
        seal(&mut st, &Uplink::Command(Command::Arm)),
        seal(&mut st, &Uplink::Heartbeat),
        seal(&mut st, &Uplink::Command(Command::Disarm)),
    );
    assert!(open_up(&mut v, &b).is_ok());
    assert_eq!(open_up(&mut v, &a), Err(AuthError::Replayed), "older than the last");
    assert_eq!(open_up(&mut v, &b), Err(AuthError::Replayed), "the same again");
    assert!(open_up(&mut v, &c).is_ok());
    assert_eq!(open_up(&mut v, &c), Err(AuthError::Replayed));
    assert_eq!((v.counters().ok, v.counters().replayed), (2, 3));
}

#[test]
fn a_captured_session_replayed_into_a_rebooted_vehicle_delivers_nothing() {
    // The whole station side of a session, as an attacker on the radio records it.
    let mut st = SecureLink::new(Role::Station, K);
    let mut v = SecureLink::new(Role::Vehicle, K);
    let mut out = [0u8; MAX_FRAME];
    let mut capture = vec![body(st.hello(nonce(1), &mut out).unwrap())];
    assert_eq!(v.open::<Uplink>(&capture[0], T0, false, || nonce(2)), Ok(Opened::SessionStarted));
    let w = body(v.welcome(&mut out).unwrap());
    st.open::<Downlink>(&w, T0, false, || nonce(0)).unwrap();
    for m in [Uplink::Command(Command::Arm), Uplink::Command(Command::TakeOff), Uplink::Heartbeat] {
        capture.push(seal(&mut st, &m));
    }
    // The vehicle reboots: a new link, a new nonce. The replayed hello starts a session the attacker cannot
    // key; every replayed command fails.
    let mut rebooted = SecureLink::new(Role::Vehicle, K);
    let mut delivered = 0;
    for b in &capture {
        if let Ok(Opened::Message(_)) = rebooted.open::<Uplink>(b, T0, false, || nonce(5)) {
            delivered += 1;
        }
    }
    assert_eq!(delivered, 0);
    assert_eq!(rebooted.counters().bad_tag, 3);
    // Without the replayed hello, the commands have no session at all.
    let mut fresh = SecureLink::new(Role::Vehicle, K);
    for b in &capture[1..] {
        assert_eq!(fresh.open::<Uplink>(b, T0, false, || nonce(6)), Err(AuthError::NoSession));
    }
    // And an old welcome replayed to a station that said hello again is not taken.
    let mut st2 = SecureLink::new(Role::Station, K);
    st2.hello(nonce(7), &mut out).unwrap();
    assert_eq!(st2.open::<Downlink>(&w, T0, false, || nonce(0)), Err(AuthError::NoSession));
    assert!(!st2.has_session());
}

#[test]
fn every_bit_flip_and_every_truncation_is_refused() {
    let (mut st, mut v) = pair(K);
    let good = seal(&mut st, &Uplink::Command(Command::Arm));
    for i in 0..good.len() {
        for bit in 0..8 {
            let mut b = good.clone();
            b[i] ^= 1 << bit;
            assert!(open_up(&mut v, &b).is_err(), "byte {i} bit {bit}");
        }
        assert!(open_up(&mut v, &good[..i]).is_err(), "cut at {i}");
    }
    assert_eq!(v.counters().ok, 0);
    // The original is still good: nothing above spent its counter.
    assert!(open_up(&mut v, &good).is_ok());
}

#[test]
fn an_unauthenticated_frame_on_a_keyed_link_is_a_downgrade() {
    let (_, mut v) = pair(K);
    let mut out = [0u8; MAX_FRAME];
    let old = body(encode(&Uplink::Command(Command::Arm), &mut out).unwrap());
    assert_eq!(open_up(&mut v, &old), Err(AuthError::Downgrade));
    let mut other = old.clone();
    other[0] = 9; // neither 1 (unauthenticated) nor 2-4 (keyed)
    assert_eq!(open_up(&mut v, &other), Err(AuthError::UnknownVersion));
    assert_eq!((v.counters().downgrade, v.counters().unknown_version, v.counters().ok), (1, 1, 0));
}

#[test]
fn a_hello_cannot_cut_a_live_session_in_flight_but_restarts_a_quiet_one() {
    let (mut st, mut v) = pair(K);
    let mut out = [0u8; MAX_FRAME];
    let hb = seal(&mut st, &Uplink::Heartbeat);
    assert!(v.open::<Uplink>(&hb, T0 + 100_000, true, || nonce(9)).is_ok());
    // A station restarting (or a hello replayed) while the vehicle flies and hears its station: refused.
    let mut st2 = SecureLink::new(Role::Station, K);
    let h = body(st2.hello(nonce(11), &mut out).unwrap());
    assert_eq!(v.open::<Uplink>(&h, T0 + 200_000, true, || nonce(12)), Err(AuthError::HelloRefused));
    // The old session still works.
    let hb2 = seal(&mut st, &Uplink::Heartbeat);
    assert!(v.open::<Uplink>(&hb2, T0 + 300_000, true, || nonce(9)).is_ok());
    // After the link was quiet for HELLO_QUIET_US, the new station gets in.
    let later = T0 + 300_000 + HELLO_QUIET_US;
    assert_eq!(v.open::<Uplink>(&h, later, true, || nonce(12)), Ok(Opened::SessionStarted));
    let w = body(v.welcome(&mut out).unwrap());
    assert_eq!(st2.open::<Downlink>(&w, later, false, || nonce(0)), Ok(Opened::SessionStarted));
    let arm = seal(&mut st2, &Uplink::Command(Command::Land));
    assert_eq!(open_up(&mut v, &arm), Ok(Opened::Message(Uplink::Command(Command::Land))));
    // The old station's frames now fail.
    let hb3 = seal(&mut st, &Uplink::Heartbeat);
    assert_eq!(open_up(&mut v, &hb3), Err(AuthError::BadTag));
}

#[test]
fn a_vehicle_frame_reflected_back_is_refused() {
    // The direction is in the tag: a downlink frame fed to the vehicle (or an uplink one to the station) fails.
    let (mut st, mut v) = pair(K);
    let down = seal(&mut v, &Downlink::CommandAck(CommandResult::Accepted(Command::Arm)));
    assert_eq!(v.open::<Downlink>(&down, T0, true, || nonce(0)), Err(AuthError::BadTag));
    let up = seal(&mut st, &Uplink::Heartbeat);
    assert_eq!(st.open::<Uplink>(&up, T0, false, || nonce(0)), Err(AuthError::BadTag));
}

#[test]
fn golden_bytes_of_a_hello() {
    // Pinned (docs/security.md): kind 3 (hello), counter 0, the nonce, the first 6 bytes of
    // HMAC-SHA256(K, "WLQA" 'U' 03 00 nonce).
    let mut st = SecureLink::new(Role::Station, [0; KEY_LEN]);
    let mut out = [0u8; MAX_FRAME];
    let b = body(st.hello([0x11; NONCE_LEN], &mut out).unwrap());
    assert_eq!(b[..2], [3, 0]);
    assert_eq!(b[2..2 + NONCE_LEN], [0x11; NONCE_LEN]);
    let full = mac(&keyed(&[0; KEY_LEN]), &[b"WLQA", &[b'U', 3], &[0], &[0x11; NONCE_LEN]]);
    assert_eq!(b[2 + NONCE_LEN..], full[..TAG_LEN]);
    assert_eq!(hex(&b[2 + NONCE_LEN..]), "21 0e 6e 08 6c 00");
    // The prepared (padded) key is the key: the same tag as HMAC keyed from the 32 bytes (a zero key cannot
    // tell a padding bug).
    let k: [u8; KEY_LEN] = core::array::from_fn(|i| i as u8 * 7 + 1);
    let mut direct = <Hmac<Sha256> as KeyInit>::new_from_slice(&k).unwrap();
    direct.update(b"WLQA");
    assert_eq!(mac(&keyed(&k), &[b"WL", b"QA"]), <[u8; 32]>::from(direct.finalize().into_bytes()));
    // HMAC-SHA256 itself: RFC 4231 test case 2 ("Jefe", "what do ya want for nothing?").
    let mut m = <Hmac<Sha256> as KeyInit>::new_from_slice(b"Jefe").unwrap();
    m.update(b"what do ya want for nothing?");
    assert_eq!(hex(&m.finalize().into_bytes()[..8]), "5b dc c1 46 bf 60 75 4e");
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect::<Vec<_>>().join(" ")
}

proptest::proptest! {
    #[test]
    fn opening_never_panics(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..600)) {
        let (_, mut v) = pair(K);
        let _ = open_up(&mut v, &bytes);
        let mut d = Decoder::new();
        for b in bytes {
            if let Some(Ok(body)) = d.push_body(b) {
                let body = body.to_vec();
                let _ = open_up(&mut v, &body);
            }
        }
    }
}

/// `FUZZ_INPUTS` mutated frames (10^7 by default, about 6 s) through the
/// decoder and the vehicle's side of the link: no panic, and not one accepted.
#[test]
fn mutated_frames_never_panic_and_are_never_accepted() {
    let n: u64 = std::env::var("FUZZ_INPUTS").ok().and_then(|v| v.parse().ok()).unwrap_or(10_000_000);
    let (mut st, mut v) = pair(K);
    let mut out = [0u8; MAX_FRAME];
    // Originals: data frames of every size class, a hello and a welcome (refused on this side anyway).
    let mut originals: Vec<Vec<u8>> = [
        Uplink::Command(Command::Arm),
        Uplink::Heartbeat,
        Uplink::TimeSync { station_time_us: 1_234_567 },
        Uplink::ParamSet { id: control_core::params::ParamId::TrajectoryZd, value: 0.8 },
    ]
    .iter()
    .map(|m| st.seal(m, &mut out).unwrap().to_vec())
    .collect();
    originals.push(SecureLink::new(Role::Station, K).hello(nonce(3), &mut out).unwrap().to_vec());
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut rnd = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let mut decoder = Decoder::new();
    let (mut accepted, mut bodies) = (0u64, 0u64);
    for _ in 0..n {
        let src = &originals[(rnd() % originals.len() as u64) as usize];
        let mut f = src.clone();
        match rnd() % 5 {
            0 | 1 => {
                for _ in 0..1 + rnd() % 3 {
                    let i = (rnd() % f.len() as u64) as usize;
                    f[i] ^= 1 << (rnd() % 8);
                }
            }
            2 => f.truncate((rnd() % f.len() as u64) as usize),
            3 => {
                let i = (rnd() % f.len() as u64) as usize;
                f[i] = rnd() as u8;
            }
            _ => {
                let len = rnd() % 80;
                f = (0..len).map(|_| rnd() as u8).collect();
            }
        }
        // The decoder sees the frame ended: a mutation that only cut the delimiter is the original again.
        f.push(0);
        if f.ends_with(&[0, 0]) {
            f.pop();
        }
        if &f == src {
            continue;
        }
        for &b in &f {
            if let Some(Ok(body)) = decoder.push_body(b) {
                bodies += 1;
                let body = body.to_vec();
                // A hello is taken only while disarmed: flying, the session stays.
                if let Ok(Opened::Message(_)) = v.open::<Uplink>(&body, T0, true, || nonce(9)) {
                    accepted += 1;
                }
            }
        }
    }
    eprintln!("{n} mutated frames, {bodies} bodies opened, counters {:?}", v.counters());
    assert_eq!(accepted, 0);
    // Most reached the tag check (the rest failed on their version, length or framing first).
    assert!(v.counters().bad_tag as u64 > n / 4, "{:?} of {n}", v.counters());
    assert!(bodies > n / 3, "{bodies} bodies of {n}");
}
