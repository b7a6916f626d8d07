//! Framing of the radio link (and of log records): one message per frame.
//!
//! ```text
//! frame   = cobs(version | payload | crc16) 0x00
//! version = WIRE_VERSION (1 byte)
//! payload = postcard encoding of the message
//! crc16   = CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) of version and payload, little endian
//! ```
//!
//! COBS (Cheshire and Baker, 1999) removes every zero byte, so `0x00` only ever ends a frame and a receiver
//! that starts in the middle of a stream, or loses bytes, resynchronises on the next `0x00`. The exact bytes
//! are specified in `docs/log-format.md` and pinned by golden tests.
use serde::{Serialize, de::DeserializeOwned};

/// Version of the wire format (the first byte of every decoded frame).
pub const WIRE_VERSION: u8 = 1;

/// Largest encoded frame, delimiter included (bytes). Longer frames are dropped as oversized.
pub const MAX_FRAME: usize = 512;

/// Why a frame could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// The output buffer is too small.
    BufferFull,
}

/// CRC-16/CCITT-FALSE lookup table (one entry per leading byte), built at compile time: 512 bytes of flash.
const CRC16_TABLE: [u16; 256] = {
    let mut t = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u16) << 8;
        let mut k = 0;
        while k < 8 {
            crc = if crc & 0x8000 != 0 { (crc << 1) ^ 0x1021 } else { crc << 1 };
            k += 1;
        }
        t[i] = crc;
        i += 1;
    }
    t
};

/// CRC-16/CCITT-FALSE (table driven, one lookup per byte).
pub fn crc16(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc = (crc << 8) ^ CRC16_TABLE[((crc >> 8) as u8 ^ b) as usize];
    }
    crc
}

/// COBS-encodes `src` into `dst` (without the trailing delimiter). Returns the encoded length.
pub fn cobs_encode(src: &[u8], dst: &mut [u8]) -> Result<usize, EncodeError> {
    let mut code_idx = 0usize;
    let mut out = 1usize;
    let mut code: u8 = 1;
    if dst.is_empty() {
        return Err(EncodeError::BufferFull);
    }
    for &b in src {
        if b == 0 {
            dst[code_idx] = code;
            code_idx = out;
            out += 1;
            code = 1;
        } else {
            *dst.get_mut(out).ok_or(EncodeError::BufferFull)? = b;
            out += 1;
            code += 1;
            if code == 0xFF {
                dst[code_idx] = code;
                code_idx = out;
                out += 1;
                code = 1;
            }
        }
        if code_idx >= dst.len() {
            return Err(EncodeError::BufferFull);
        }
    }
    *dst.get_mut(code_idx).ok_or(EncodeError::BufferFull)? = code;
    Ok(out)
}

/// COBS-decodes `buf` in place. Returns the decoded length, or `None` for invalid input (a zero byte, or a
/// code pointing past the end).
pub fn cobs_decode_in_place(buf: &mut [u8]) -> Option<usize> {
    let mut read = 0usize;
    let mut write = 0usize;
    while read < buf.len() {
        let code = buf[read];
        if code == 0 {
            return None;
        }
        let end = read + code as usize;
        if end > buf.len() {
            return None;
        }
        read += 1;
        while read < end {
            let b = buf[read];
            if b == 0 {
                return None;
            }
            buf[write] = b;
            write += 1;
            read += 1;
        }
        if code != 0xFF && read < buf.len() {
            buf[write] = 0;
            write += 1;
        }
    }
    Some(write)
}

/// Encodes one message as a complete frame (delimiter included) into `out`. Returns the frame's bytes.
pub fn encode<'a, T: Serialize>(msg: &T, out: &'a mut [u8]) -> Result<&'a [u8], EncodeError> {
    let mut raw = [0u8; MAX_FRAME];
    raw[0] = WIRE_VERSION;
    let n = postcard::to_slice(msg, &mut raw[1..MAX_FRAME - 2]).map_err(|_| EncodeError::BufferFull)?.len();
    let crc = crc16(&raw[..1 + n]);
    raw[1 + n..3 + n].copy_from_slice(&crc.to_le_bytes());
    let len = cobs_encode(&raw[..3 + n], out)?;
    if len + 1 > MAX_FRAME {
        return Err(EncodeError::BufferFull);
    }
    *out.get_mut(len).ok_or(EncodeError::BufferFull)? = 0;
    Ok(&out[..len + 1])
}

/// Counters of everything the decoder dropped, by kind.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, postcard_schema::Schema,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DecodeCounters {
    /// Frames decoded and delivered.
    pub ok: u32,
    /// Frames that were not valid COBS (garbage, lost bytes).
    pub cobs: u32,
    /// Frames longer than [`MAX_FRAME`] (dropped up to the next delimiter).
    pub oversized: u32,
    /// Frames too short to hold a version and a CRC.
    pub truncated: u32,
    /// Frames whose CRC did not match.
    pub bad_crc: u32,
    /// Frames of another wire version.
    pub unknown_version: u32,
    /// Frames with a valid CRC whose payload did not decode (unknown message, wrong length).
    pub malformed: u32,
}

impl DecodeCounters {
    /// All dropped frames.
    pub fn errors(&self) -> u32 {
        self.cobs + self.oversized + self.truncated + self.bad_crc + self.unknown_version + self.malformed
    }
}

/// Outcome of one complete frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// Not valid COBS.
    Cobs,
    /// Longer than [`MAX_FRAME`].
    Oversized,
    /// Too short.
    Truncated,
    /// CRC mismatch.
    BadCrc,
    /// Another wire version.
    UnknownVersion(u8),
    /// The payload did not decode.
    Malformed,
}

/// A streaming decoder: feed it bytes as they arrive; it returns each message as its frame completes.
/// It never panics, keeps counters of every error kind, and recovers at the next delimiter.
pub struct Decoder {
    buf: [u8; MAX_FRAME],
    len: usize,
    overflow: bool,
    counters: DecodeCounters,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_FRAME],
            len: 0,
            overflow: false,
            counters: DecodeCounters {
                ok: 0,
                cobs: 0,
                oversized: 0,
                truncated: 0,
                bad_crc: 0,
                unknown_version: 0,
                malformed: 0,
            },
        }
    }

    /// The counters.
    pub fn counters(&self) -> DecodeCounters {
        self.counters
    }

    /// Feeds one byte. Returns `Some(result)` when the byte completed a frame (an empty frame, two delimiters
    /// in a row, is skipped silently).
    pub fn push<T: DeserializeOwned>(&mut self, byte: u8) -> Option<Result<T, FrameError>> {
        let len = match self.collect(byte)? {
            Ok(len) => len,
            Err(e) => return Some(Err(e)),
        };
        let r = self.decode_frame::<T>(len);
        match &r {
            Ok(_) => self.counters.ok += 1,
            Err(FrameError::Cobs) => self.counters.cobs += 1,
            Err(FrameError::Oversized) => self.counters.oversized += 1,
            Err(FrameError::Truncated) => self.counters.truncated += 1,
            Err(FrameError::BadCrc) => self.counters.bad_crc += 1,
            Err(FrameError::UnknownVersion(_)) => self.counters.unknown_version += 1,
            Err(FrameError::Malformed) => self.counters.malformed += 1,
        }
        Some(r)
    }

    /// Feeds one byte of a keyed link. When it completes a frame, returns the frame's body with COBS undone,
    /// for [`crate::auth::SecureLink::open`] (which counts what it accepts and refuses), or the framing error
    /// (COBS, oversized), counted here.
    pub fn push_body(&mut self, byte: u8) -> Option<Result<&[u8], FrameError>> {
        let len = match self.collect(byte)? {
            Ok(len) => len,
            Err(e) => return Some(Err(e)),
        };
        match cobs_decode_in_place(&mut self.buf[..len]) {
            Some(n) => Some(Ok(&self.buf[..n])),
            None => {
                self.counters.cobs += 1;
                Some(Err(FrameError::Cobs))
            }
        }
    }

    /// Buffers one byte; at a delimiter, the length of the frame collected (an empty frame, two delimiters in
    /// a row, is skipped silently; an oversized one is counted).
    fn collect(&mut self, byte: u8) -> Option<Result<usize, FrameError>> {
        if byte != 0 {
            if self.len < self.buf.len() {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflow = true;
            }
            return None;
        }
        let len = core::mem::replace(&mut self.len, 0);
        if core::mem::replace(&mut self.overflow, false) {
            self.counters.oversized += 1;
            return Some(Err(FrameError::Oversized));
        }
        if len == 0 {
            return None;
        }
        Some(Ok(len))
    }

    fn decode_frame<T: DeserializeOwned>(&mut self, len: usize) -> Result<T, FrameError> {
        let n = cobs_decode_in_place(&mut self.buf[..len]).ok_or(FrameError::Cobs)?;
        decode_raw(&self.buf[..n])
    }
}

/// Decodes one COBS-decoded frame body (`version | payload | crc16`).
pub fn decode_raw<T: DeserializeOwned>(raw: &[u8]) -> Result<T, FrameError> {
    if raw.len() < 3 {
        return Err(FrameError::Truncated);
    }
    let (body, crc) = raw.split_at(raw.len() - 2);
    if crc16(body) != u16::from_le_bytes([crc[0], crc[1]]) {
        return Err(FrameError::BadCrc);
    }
    if body[0] != WIRE_VERSION {
        return Err(FrameError::UnknownVersion(body[0]));
    }
    match postcard::take_from_bytes::<T>(&body[1..]) {
        Ok((msg, [])) => Ok(msg),
        _ => Err(FrameError::Malformed),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Uplink;
    use control_core::Command;

    fn frame_of(msg: &Uplink) -> Vec<u8> {
        let mut out = [0u8; MAX_FRAME];
        encode(msg, &mut out).unwrap().to_vec()
    }

    fn decode_all(bytes: &[u8], d: &mut Decoder) -> Vec<Result<Uplink, FrameError>> {
        bytes.iter().filter_map(|&b| d.push::<Uplink>(b)).collect()
    }

    #[test]
    fn crc_and_cobs_known_values() {
        // CRC-16/CCITT-FALSE check value.
        assert_eq!(crc16(b"123456789"), 0x29B1);
        // COBS examples from the paper / Wikipedia.
        let mut out = [0u8; 16];
        let n = cobs_encode(&[0x11, 0x22, 0x00, 0x33], &mut out).unwrap();
        assert_eq!(&out[..n], &[0x03, 0x11, 0x22, 0x02, 0x33]);
        let n = cobs_encode(&[0x00], &mut out).unwrap();
        assert_eq!(&out[..n], &[0x01, 0x01]);
        let mut long = [1u8; 300];
        long[100] = 0;
        let mut enc = [0u8; 320];
        let n = cobs_encode(&long, &mut enc).unwrap();
        assert!(!enc[..n].contains(&0));
        let back = cobs_decode_in_place(&mut enc[..n]).unwrap();
        assert_eq!(&enc[..back], &long[..]);
    }

    #[test]
    fn table_crc_matches_the_bitwise_definition() {
        let bitwise = |data: &[u8]| {
            let mut crc: u16 = 0xFFFF;
            for &b in data {
                crc ^= (b as u16) << 8;
                for _ in 0..8 {
                    crc = if crc & 0x8000 != 0 { (crc << 1) ^ 0x1021 } else { crc << 1 };
                }
            }
            crc
        };
        let data: Vec<u8> = (0..2000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
        for n in [0, 1, 2, 9, 255, 256, 1999] {
            assert_eq!(crc16(&data[..n]), bitwise(&data[..n]), "length {n}");
        }
    }

    #[test]
    fn golden_bytes_of_a_command() {
        // Pinned: changing these bytes is a wire-format change (bump WIRE_VERSION, update docs/log-format.md).
        // Body: version 1, Uplink variant 1 (Command), Command variant 0 (Arm); CRC-16 0xC89D little endian;
        // COBS: [03 01 01] [03 9D C8]; delimiter 00.
        assert_eq!(crc16(&[1, 1, 0]), 0xC89D);
        assert_eq!(frame_of(&Uplink::Command(Command::Arm)), [0x03, 0x01, 0x01, 0x03, 0x9D, 0xC8, 0x00]);
        // ParamSet: variant 3, ParamId 1 (TrajectoryZd), f32 1.0 little endian (00 00 80 3F).
        let f = frame_of(&Uplink::ParamSet { id: control_core::params::ParamId::TrajectoryZd, value: 1.0 });
        let mut raw = vec![WIRE_VERSION, 3, 1, 0x00, 0x00, 0x80, 0x3F];
        raw.extend(crc16(&raw).to_le_bytes());
        let mut enc = [0u8; 32];
        let n = cobs_encode(&raw, &mut enc).unwrap();
        assert_eq!(f[..n], enc[..n]);
        // Heartbeat: version 1, variant 2, no zero byte: one COBS block of 5.
        assert_eq!(frame_of(&Uplink::Heartbeat)[..3], [0x05, 0x01, 0x02]);
        // TimeSync: version 1, variant 6, station time 1_000_000 us as a varint (C0 84 3D); CRC-16 little
        // endian; no zero byte: one COBS block.
        let raw = [WIRE_VERSION, 6, 0xC0, 0x84, 0x3D];
        assert_eq!(crc16(&raw), 0x8A91);
        assert_eq!(
            frame_of(&Uplink::TimeSync { station_time_us: 1_000_000 }),
            [0x08, 0x01, 0x06, 0xC0, 0x84, 0x3D, 0x91, 0x8A, 0x00]
        );
        // Its answer: Downlink variant 3, both times as varints.
        let mut buf = [0u8; 32];
        let f =
            encode(&crate::Downlink::TimeSync { station_time_us: 1_000_000, vehicle_time_us: 2 }, &mut buf)
                .unwrap();
        let mut raw = vec![WIRE_VERSION, 3, 0xC0, 0x84, 0x3D, 0x02];
        raw.extend(crc16(&raw).to_le_bytes());
        let mut enc = [0u8; 32];
        let n = cobs_encode(&raw, &mut enc).unwrap();
        assert_eq!(f[..n], enc[..n]);
    }

    #[test]
    fn golden_bytes_of_a_configuration_piece_and_its_answer() {
        let body = |m: &[u8]| {
            let mut raw = m.to_vec();
            raw.extend(crc16(&raw).to_le_bytes());
            raw
        };
        let decode = |f: &[u8]| {
            let mut raw = f[..f.len() - 1].to_vec();
            let n = cobs_decode_in_place(&mut raw).unwrap();
            raw.truncate(n);
            raw
        };
        let mut buf = [0u8; 128];
        // Uplink 9 (Config): CRC-32 0x12345678 as a varint (F8 AC D1 91 01), total 700 (BC 05), offset 64
        // (40), length 3, then the 32 bytes (3 of them used, the rest zeros).
        let mut bytes = [0u8; crate::CONFIG_CHUNK_BYTES];
        bytes[..3].copy_from_slice(&[0xAA, 0xBB, 0xCC]);
        let chunk = crate::ConfigChunk { crc32: 0x1234_5678, total_len: 700, offset: 64, len: 3, bytes };
        let f = encode(&Uplink::Config(chunk), &mut buf).unwrap().to_vec();
        let mut want =
            vec![WIRE_VERSION, 9, 0xF8, 0xAC, 0xD1, 0x91, 0x01, 0xBC, 0x05, 0x40, 0x03, 0xAA, 0xBB, 0xCC];
        want.extend([0u8; 29]);
        assert_eq!(decode(&f), body(&want));
        assert_eq!(crc16(&want), 0x8364);
        // Downlink 6 (ConfigAck): CRC-32 0x12345678, Applied (0) with saved sequence Some(3); Refused (1)
        // Invalid (4).
        let ack = crate::ConfigAck {
            crc32: 0x1234_5678,
            outcome: crate::ConfigOutcome::Applied { saved_sequence: Some(3) },
        };
        let f = encode(&crate::Downlink::ConfigAck(ack), &mut buf).unwrap().to_vec();
        assert_eq!(decode(&f), body(&[WIRE_VERSION, 6, 0xF8, 0xAC, 0xD1, 0x91, 0x01, 0, 1, 3]));
        // COBS: [08 01 06 F8 AC D1 91 01] [05 01 03 EE 08], CRC-16 0x08EE; delimiter 00.
        assert_eq!(f, [0x08, 0x01, 0x06, 0xF8, 0xAC, 0xD1, 0x91, 0x01, 0x05, 0x01, 0x03, 0xEE, 0x08, 0x00]);
        let ack = crate::ConfigAck {
            crc32: 0x1234_5678,
            outcome: crate::ConfigOutcome::Refused(crate::ConfigRefusal::Invalid),
        };
        let f = encode(&crate::Downlink::ConfigAck(ack), &mut buf).unwrap().to_vec();
        assert_eq!(decode(&f), body(&[WIRE_VERSION, 6, 0xF8, 0xAC, 0xD1, 0x91, 0x01, 1, 4]));
    }

    #[test]
    fn golden_bytes_of_the_link_status_and_the_unauthenticated_refusal() {
        use control_core::{Command, CommandResult, Refusal};
        let frame = |raw: &[u8]| {
            let mut raw = raw.to_vec();
            raw.extend(crc16(&raw).to_le_bytes());
            let mut enc = [0u8; 64];
            let n = cobs_encode(&raw, &mut enc).unwrap();
            let mut v = enc[..n].to_vec();
            v.push(0);
            v
        };
        let mut buf = [0u8; 64];
        // CommandAck (Downlink 1), Refused (1), Arm (0), Unauthenticated (Refusal 5).
        let ack = crate::Downlink::CommandAck(CommandResult::Refused(Command::Arm, Refusal::Unauthenticated));
        let f = encode(&ack, &mut buf).unwrap().to_vec();
        assert_eq!(f, frame(&[WIRE_VERSION, 1, 1, 0, 5]));
        assert_eq!(f, [0x04, 0x01, 0x01, 0x01, 0x04, 0x05, 0x7C, 0xAA, 0x00]);
        // LinkStatus (Downlink 5): authenticated, 2 arms refused, no framing error, 300 frames accepted (AC 02),
        // one session, no refusal.
        let status = crate::LinkStatus {
            authenticated: true,
            arm_refused: 2,
            framing_errors: 0,
            auth: crate::auth::AuthCounters { ok: 300, sessions: 1, ..Default::default() },
        };
        let f = encode(&crate::Downlink::LinkStatus(status), &mut buf).unwrap().to_vec();
        assert_eq!(f, frame(&[WIRE_VERSION, 5, 1, 2, 0, 0xAC, 0x02, 1, 0, 0, 0, 0, 0, 0, 0, 0]));
        let mut d = Decoder::new();
        let got: Vec<_> = f.iter().filter_map(|&b| d.push::<crate::Downlink>(b)).collect();
        assert_eq!(got, [Ok(crate::Downlink::LinkStatus(status))]);
        assert_eq!(
            f,
            [
                0x05, 0x01, 0x05, 0x01, 0x02, 0x04, 0xAC, 0x02, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01,
                0x01, 0x03, 0x77, 0xE3, 0x00
            ]
        );
    }

    #[test]
    fn flow_measurements_round_trip_and_fit_the_link() {
        use vision_core::flow::{FlowStats, NoFlowReason};
        let stats = FlowStats {
            flow: geometry::Vec2::new(-0.0123, 0.0041),
            predicted_rotation: geometry::Vec3::new(0.001, -0.002, 0.0005),
            mean_pos: geometry::Vec2::new(0.01, -0.02),
            mean_sq: [0.09, 0.05, -0.001],
            inliers: 44,
            selected: 48,
            residual_rms: 0.0004,
            median_flow_px: geometry::Vec2::new(-1.7, 0.57),
            quality: 0.92,
        };
        let ok = crate::FlowMeasurement {
            t_prev_us: 10_000_000,
            t_next_us: 10_016_667,
            frame_seq: 600,
            result: Ok(stats),
        };
        let none = crate::FlowMeasurement { result: Err(NoFlowReason::NoTexture), ..ok };
        let mut dec = Decoder::new();
        for m in [Uplink::Flow(ok), Uplink::Flow(none)] {
            let f = frame_of(&m);
            // At 60 Hz, 96 bytes are 5.8 kB/s: half of a 115.2 kbit/s telemetry radio, the rest for vision.
            assert!(f.len() <= 96, "{} bytes", f.len());
            let got: Vec<Result<Uplink, FrameError>> = f.iter().filter_map(|b| dec.push(*b)).collect();
            assert_eq!(got, vec![Ok(m)]);
        }
    }

    #[test]
    fn round_trip_and_resync() {
        let msgs = [Uplink::Heartbeat, Uplink::Command(Command::TakeOff), Uplink::Command(Command::Land)];
        let mut stream = vec![0x55, 0x13, 0x00]; // garbage, then a delimiter
        for m in &msgs {
            stream.extend(frame_of(m));
        }
        let mut d = Decoder::new();
        let out = decode_all(&stream, &mut d);
        assert_eq!(out.len(), 4);
        assert!(out[0].is_err());
        assert_eq!(out[1..].iter().map(|r| *r.as_ref().unwrap()).collect::<Vec<_>>(), msgs.to_vec());
        assert_eq!(d.counters().ok, 3);
        assert_eq!(d.counters().errors(), 1);
    }

    #[test]
    fn every_error_kind_is_counted_and_the_next_frame_decodes() {
        let good = frame_of(&Uplink::Command(Command::Arm));
        let mut d = Decoder::new();
        // Bad CRC: flip a payload bit inside the COBS body (keep it nonzero).
        let mut bad = good.clone();
        bad[2] ^= 0x04;
        // Truncated: a frame that lost its tail.
        let trunc = [good[0] - 3, 0x01, 0x00];
        // Oversized: more than MAX_FRAME bytes without a delimiter.
        let mut over = vec![0x42u8; MAX_FRAME + 10];
        over.push(0);
        // Unknown version: re-encode a body with version 9.
        let body = [9u8, 1, 0];
        let mut raw = body.to_vec();
        raw.extend(crc16(&body).to_le_bytes());
        let mut enc = [0u8; 16];
        let n = cobs_encode(&raw, &mut enc).unwrap();
        let mut wrong_version = enc[..n].to_vec();
        wrong_version.push(0);
        // Malformed: valid CRC and version, unknown message variant.
        let body = [WIRE_VERSION, 77];
        let mut raw = body.to_vec();
        raw.extend(crc16(&body).to_le_bytes());
        let n = cobs_encode(&raw, &mut enc).unwrap();
        let mut malformed = enc[..n].to_vec();
        malformed.push(0);
        // Not COBS: a code pointing past the end.
        let garbage = [0x09u8, 0x01, 0x00];
        for (bytes, what) in [
            (&bad[..], "crc"),
            (&trunc[..], "truncated"),
            (&over[..], "oversized"),
            (&wrong_version[..], "version"),
            (&malformed[..], "malformed"),
            (&garbage[..], "cobs"),
        ] {
            let r = decode_all(bytes, &mut d);
            assert_eq!(r.len(), 1, "{what}");
            assert!(r[0].is_err(), "{what}");
            let r = decode_all(&good, &mut d);
            assert_eq!(r, vec![Ok(Uplink::Command(Command::Arm))], "recovers after {what}");
        }
        let c = d.counters();
        assert_eq!(
            (c.bad_crc, c.truncated, c.oversized, c.unknown_version, c.malformed, c.cobs, c.ok),
            (1, 1, 1, 1, 1, 1, 6),
            "{c:?}"
        );
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(2000))]
        /// Any byte stream: no panic, every completed frame is counted once, and a good frame appended
        /// afterwards always decodes.
        #[test]
        fn decoder_never_panics_and_recovers(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..2000)) {
            let mut d = Decoder::new();
            let n = decode_all(&bytes, &mut d).len() as u32;
            let c = d.counters();
            proptest::prop_assert_eq!(c.ok + c.errors(), n);
            let mut tail = vec![0u8];
            tail.extend(frame_of(&Uplink::Command(Command::Disarm)));
            let out = decode_all(&tail, &mut d);
            proptest::prop_assert_eq!(out.last().cloned(), Some(Ok(Uplink::Command(Command::Disarm))));
        }

        /// Encoding then decoding any command or heartbeat is the identity, and no encoded frame contains a
        /// zero before its end.
        #[test]
        fn encode_decode_identity(which in 0u8..9, param in 0usize..35, value in proptest::prelude::any::<f32>()) {
            let id = control_core::params::ParamId::ALL[param];
            let msg = match which {
                7 => Uplink::ParamGet(id),
                8 => Uplink::ParamSet { id, value: if value.is_nan() { 0.0 } else { value } },
                0 => Uplink::Heartbeat,
                1 => Uplink::Command(Command::Arm),
                2 => Uplink::Command(Command::Disarm),
                3 => Uplink::Command(Command::TakeOff),
                4 => Uplink::Command(Command::StartTracking),
                5 => Uplink::Command(Command::StopTracking),
                _ => Uplink::Command(Command::Land),
            };
            let f = frame_of(&msg);
            proptest::prop_assert!(!f[..f.len() - 1].contains(&0));
            let mut d = Decoder::new();
            proptest::prop_assert_eq!(decode_all(&f, &mut d), vec![Ok(msg)]);
        }
    }
}
