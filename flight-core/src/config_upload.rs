//! A whole flight configuration ([`FlightConfig`]: the flight parameters, the forward camera and the line, the
//! use of the flow) sent to the vehicle over the radio link in pieces ([`protocol::ConfigChunk`]), on the ground.
//!
//! The upload is the configuration's schema key (the parameter store's, [`crate::param_store::SCHEMA_KEY`]: a
//! set of another layout is refused by name, never misread) followed by its postcard bytes, named by the CRC-32
//! of the whole. [`chunks`] cuts it (the station's and the simulator's side); [`ConfigUpload`] puts it back
//! together on the vehicle: the pieces may come in any order and more than once, a piece of another upload starts
//! that one afresh, and once every piece is in, the whole is checked (CRC, layout, decoding, every check of
//! [`FlightStack::check_config`]) and handed to the caller, which rebuilds its flight stack from it if disarmed
//! and stores it in flash ([`crate::param_store`]) so that it is loaded at the next boot.
use crate::param_store::{MAX_BODY, SCHEMA_KEY};
use crate::{FlightConfig, FlightStack};
use protocol::{CONFIG_CHUNK_BYTES, ConfigChunk, ConfigRefusal};

/// The longest upload: the schema key and the largest body the store keeps.
pub const MAX_UPLOAD: usize = SCHEMA_KEY.len() + MAX_BODY;
/// Pieces of the longest upload.
pub const MAX_CHUNKS: usize = MAX_UPLOAD.div_ceil(CONFIG_CHUNK_BYTES);
const _: () = assert!(MAX_CHUNKS <= 64, "one bit of a u64 per piece");

const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// The pieces of `cfg`'s upload and its CRC-32 (which names it in the vehicle's [`protocol::ConfigAck`]).
/// Refused when the configuration is not valid ([`FlightStack::check_config`]) or too large.
pub fn chunks(cfg: &FlightConfig) -> Result<(u32, heapless::Vec<ConfigChunk, MAX_CHUNKS>), ConfigRefusal> {
    FlightStack::check_config(cfg).map_err(|_| ConfigRefusal::Invalid)?;
    let mut buf = [0u8; MAX_UPLOAD];
    buf[..SCHEMA_KEY.len()].copy_from_slice(&SCHEMA_KEY);
    let n = postcard::to_slice(cfg, &mut buf[SCHEMA_KEY.len()..]).map_err(|_| ConfigRefusal::TooLarge)?.len();
    let total = SCHEMA_KEY.len() + n;
    let crc32 = CRC32.checksum(&buf[..total]);
    let mut out = heapless::Vec::new();
    for (k, piece) in buf[..total].chunks(CONFIG_CHUNK_BYTES).enumerate() {
        let mut bytes = [0u8; CONFIG_CHUNK_BYTES];
        bytes[..piece.len()].copy_from_slice(piece);
        let chunk = ConfigChunk {
            crc32,
            total_len: total as u16,
            offset: (k * CONFIG_CHUNK_BYTES) as u16,
            len: piece.len() as u8,
            bytes,
        };
        // Cannot fail: MAX_CHUNKS pieces of MAX_UPLOAD bytes at most.
        let _ = out.push(chunk);
    }
    Ok((crc32, out))
}

/// A configuration upload being put back together on the vehicle.
#[derive(Clone, Debug)]
pub struct ConfigUpload {
    /// The upload's CRC-32 and length, while one is under way.
    current: Option<(u32, u16)>,
    /// Which pieces arrived (bit `k`: the piece at `k * CONFIG_CHUNK_BYTES`).
    have: u64,
    buf: [u8; MAX_UPLOAD],
}

impl Default for ConfigUpload {
    fn default() -> Self {
        Self::new()
    }
}

impl ConfigUpload {
    /// Nothing under way.
    pub const fn new() -> Self {
        Self { current: None, have: 0, buf: [0u8; MAX_UPLOAD] }
    }

    /// Takes a piece. Returns the upload's CRC-32 and its outcome when it is whole (the configuration, or why
    /// not), or at once when the piece itself cannot belong to any upload; `None` while pieces are missing.
    pub fn push(&mut self, c: &ConfigChunk) -> Option<(u32, Result<FlightConfig, ConfigRefusal>)> {
        let (total, offset, len) = (c.total_len as usize, c.offset as usize, c.len as usize);
        let refuse = |s: &mut Self, r| {
            s.current = None;
            Some((c.crc32, Err(r)))
        };
        if total > MAX_UPLOAD {
            return refuse(self, ConfigRefusal::TooLarge);
        }
        // A piece must sit on the grid, hold what its place holds, and lie within the upload.
        let expected = total.saturating_sub(offset).min(CONFIG_CHUNK_BYTES);
        if total == 0 || !offset.is_multiple_of(CONFIG_CHUNK_BYTES) || offset >= total || len != expected {
            return refuse(self, ConfigRefusal::Damaged);
        }
        if self.current != Some((c.crc32, c.total_len)) {
            self.current = Some((c.crc32, c.total_len));
            self.have = 0;
        }
        self.buf[offset..offset + len].copy_from_slice(&c.bytes[..len]);
        self.have |= 1u64 << (offset / CONFIG_CHUNK_BYTES);
        let pieces = total.div_ceil(CONFIG_CHUNK_BYTES);
        let all = if pieces == 64 { u64::MAX } else { (1u64 << pieces) - 1 };
        if self.have != all {
            return None;
        }
        self.current = None;
        Some((c.crc32, Self::check(&self.buf[..total], c.crc32)))
    }

    /// The configuration in a whole upload.
    fn check(bytes: &[u8], crc32: u32) -> Result<FlightConfig, ConfigRefusal> {
        if CRC32.checksum(bytes) != crc32 {
            return Err(ConfigRefusal::Damaged);
        }
        let (key, body) = bytes.split_at(SCHEMA_KEY.len().min(bytes.len()));
        if key != SCHEMA_KEY {
            return Err(ConfigRefusal::OtherLayout);
        }
        let cfg = match postcard::take_from_bytes::<FlightConfig>(body) {
            Ok((cfg, [])) => cfg,
            _ => return Err(ConfigRefusal::Undecodable),
        };
        FlightStack::check_config(&cfg).map_err(|_| ConfigRefusal::Invalid)?;
        Ok(cfg)
    }
}

/// What becomes of a whole upload ([`ConfigUpload::push`]'s outcome) on a vehicle in `mode`: taken only while
/// disarmed, since it rebuilds the flight stack (the estimator starts afresh) and storing it stalls the core for
/// a flash erase; refused as [`ConfigRefusal::Armed`] in every other mode, motors-off emergency included.
pub fn take_when_disarmed(
    outcome: Result<FlightConfig, ConfigRefusal>,
    mode: control_core::FlightMode,
) -> Result<FlightConfig, ConfigRefusal> {
    let cfg = outcome?;
    if mode != control_core::FlightMode::Disarmed {
        return Err(ConfigRefusal::Armed);
    }
    Ok(cfg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_whole_upload_is_taken_only_while_disarmed() {
        use control_core::FlightMode as M;
        let cfg = FlightConfig::paper();
        assert!(take_when_disarmed(Ok(cfg), M::Disarmed).is_ok());
        for m in
            [M::Armed, M::TakeOff, M::Hover, M::Tracking, M::VisionHold, M::Landing, M::Emergency, M::Manual]
        {
            assert_eq!(take_when_disarmed(Ok(cfg), m).err(), Some(ConfigRefusal::Armed), "{m:?}");
        }
        // A refusal of the upload itself stays what it is.
        assert_eq!(
            take_when_disarmed(Err(ConfigRefusal::Damaged), M::Hover).err(),
            Some(ConfigRefusal::Damaged)
        );
    }

    fn other() -> FlightConfig {
        let mut c = FlightConfig::paper();
        c.control.gains.altitude.a_z1 *= 1.5;
        c.vision.target.x_end_m = 2.0;
        c.flow.min_quality = 0.5;
        c
    }

    #[test]
    fn an_upload_in_any_order_and_with_repeats_gives_the_configuration_back() {
        let cfg = other();
        let (crc, pieces) = chunks(&cfg).unwrap();
        assert!(pieces.len() > 10 && pieces.len() <= MAX_CHUNKS, "{}", pieces.len());
        let mut up = ConfigUpload::new();
        // Reversed, each piece but the first twice: nothing until the first one, the last missing, is in.
        for p in pieces[1..].iter().rev().flat_map(|p| [p, p]) {
            assert_eq!(up.push(p), None);
        }
        assert_eq!(up.push(&pieces[0]), Some((crc, Ok(cfg))));
        // The same upload again: answered again.
        let mut last = None;
        for p in &pieces {
            last = up.push(p);
        }
        assert_eq!(last, Some((crc, Ok(cfg))));
    }

    #[test]
    fn damage_other_layouts_and_invalid_sets_are_refused_by_name() {
        let (crc, pieces) = chunks(&other()).unwrap();
        let run = |pieces: &[ConfigChunk]| {
            let mut up = ConfigUpload::new();
            pieces.iter().filter_map(|p| up.push(p)).last()
        };
        // A flipped bit in the body: the CRC fails.
        let mut bad = pieces.clone();
        bad[5].bytes[3] ^= 0x04;
        assert_eq!(run(&bad), Some((crc, Err(ConfigRefusal::Damaged))));
        // Another layout's schema key (with a CRC that matches it): named as such.
        let mut bytes: std::vec::Vec<u8> =
            pieces.iter().flat_map(|p| p.bytes[..p.len as usize].to_vec()).collect();
        bytes[0] ^= 1;
        let reframe = |bytes: &[u8]| -> std::vec::Vec<ConfigChunk> {
            let crc = CRC32.checksum(bytes);
            bytes
                .chunks(CONFIG_CHUNK_BYTES)
                .enumerate()
                .map(|(k, b)| {
                    let mut a = [0u8; CONFIG_CHUNK_BYTES];
                    a[..b.len()].copy_from_slice(b);
                    ConfigChunk {
                        crc32: crc,
                        total_len: bytes.len() as u16,
                        offset: (k * CONFIG_CHUNK_BYTES) as u16,
                        len: b.len() as u8,
                        bytes: a,
                    }
                })
                .collect()
        };
        let r = run(&reframe(&bytes)).unwrap();
        assert_eq!(r.1, Err(ConfigRefusal::OtherLayout));
        bytes[0] ^= 1;
        // A body cut short, or with a byte too many: it does not decode.
        assert_eq!(run(&reframe(&bytes[..bytes.len() - 3])).unwrap().1, Err(ConfigRefusal::Undecodable));
        let mut longer = bytes.clone();
        longer.push(0);
        assert_eq!(run(&reframe(&longer)).unwrap().1, Err(ConfigRefusal::Undecodable));
        // A set that decodes but fails the checks (a negative line): invalid; `chunks` refuses it up front.
        let mut invalid = other();
        invalid.vision.target.x_end_m = -1.0;
        assert_eq!(chunks(&invalid).unwrap_err(), ConfigRefusal::Invalid);
        let mut b = SCHEMA_KEY.to_vec();
        let mut body = [0u8; MAX_BODY];
        b.extend_from_slice(postcard::to_slice(&invalid, &mut body).unwrap());
        assert_eq!(run(&reframe(&b)).unwrap().1, Err(ConfigRefusal::Invalid));
        // Pieces that cannot belong to an upload: off the grid, too long, beyond the end, or an upload larger
        // than any set.
        let mut up = ConfigUpload::new();
        for (f, want) in [
            ((|c: &mut ConfigChunk| c.offset += 1) as fn(&mut ConfigChunk), ConfigRefusal::Damaged),
            (|c| c.len -= 1, ConfigRefusal::Damaged),
            (|c| c.offset = c.total_len + 32, ConfigRefusal::Damaged),
            (|c| c.total_len = 0, ConfigRefusal::Damaged),
            (|c| c.total_len = MAX_UPLOAD as u16 + 1, ConfigRefusal::TooLarge),
        ] {
            let mut c = pieces[0];
            f(&mut c);
            assert_eq!(up.push(&c), Some((crc, Err(want))));
        }
        // The largest upload there can be is taken: its first piece waits for the others.
        let mut c = pieces[0];
        c.total_len = MAX_UPLOAD as u16;
        assert_eq!(up.push(&c), None);
    }

    #[test]
    fn a_piece_of_another_upload_starts_that_one_afresh() {
        let (_, a) = chunks(&FlightConfig::paper()).unwrap();
        let (crc_b, b) = chunks(&other()).unwrap();
        let mut up = ConfigUpload::new();
        // Half of upload a, then all of b: b is whole, a's half does not count.
        for p in &a[..a.len() / 2] {
            assert_eq!(up.push(p), None);
        }
        let got = b.iter().filter_map(|p| up.push(p)).last();
        assert_eq!(got, Some((crc_b, Ok(other()))));
        // Half of a, then b but its first piece: a's first piece does not stand in for b's, so b waits for it.
        for p in &a[..a.len() / 2] {
            assert_eq!(up.push(p), None);
        }
        for p in &b[1..] {
            assert_eq!(up.push(p), None);
        }
        assert_eq!(up.push(&b[0]), Some((crc_b, Ok(other()))));
    }
}
