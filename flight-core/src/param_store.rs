//! The flight configuration (the flight parameters, the forward camera and the line, the use of the flow:
//! [`FlightConfig`]) kept in flash across power cycles, in two slots so that a power cut while a set is written
//! loses nothing: the old set stays valid until the new one is whole.
//!
//! A slot is one or more erase sectors. It holds a header and the set's postcard bytes:
//!
//! | bytes | field |
//! |---|---|
//! | 0-3 | magic `WLQP` |
//! | 4-5 | store format, little-endian ([`STORE_FORMAT`]) |
//! | 6-7 | body length |
//! | 8-15 | the schema key of [`FlightConfig`] (postcard-schema's key of the type: a set of another layout is never read as this one) |
//! | 16-19 | sequence number (the newest set has the highest) |
//! | 20-23 | CRC-32 (ISO-HDLC) over bytes 0-19 and the body |
//! | 24-27 | commit word `0x434F4D54`, written last |
//! | 28- | body |
//!
//! Saving erases the slot that does not hold the newest valid set, writes the header without its commit word
//! and the body, then the commit word. A slot counts only with its magic, format, schema key, CRC and commit
//! word right, a body that decodes and a set that passes every check of a flight stack's configuration
//! ([`FlightStack::check_config`]); loading takes the valid slot with the highest sequence. A cut during the erase or the writes leaves that slot invalid and the other one as
//! it was. The flash is behind `embedded-storage`'s `NorFlash` (the HAL's flash on the board, a simulated one in
//! the tests); the algorithms never read a clock.
use crate::{FlightConfig, FlightStack};
use embedded_storage::nor_flash::NorFlash;

/// The slot's magic.
pub const MAGIC: [u8; 4] = *b"WLQP";
/// The store's layout version (1 held the flight parameters alone; 2 the whole flight configuration).
pub const STORE_FORMAT: u16 = 2;
/// The commit word, written after everything else.
pub const COMMIT: u32 = 0x434F_4D54;
/// Header bytes before the body.
pub const HEADER_LEN: usize = 28;
/// The largest body (postcard bytes of a set).
pub const MAX_BODY: usize = 1024;
/// The schema key of the stored type.
pub const SCHEMA_KEY: [u8; 8] =
    postcard_schema::key::Key::for_path::<FlightConfig>("wlq/flight-config").to_bytes();

const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Why a slot was not taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SlotProblem {
    /// Erased, or never written (no magic).
    Empty,
    /// Written by another store format.
    Format,
    /// A set of another parameter layout (an older or newer firmware).
    Schema,
    /// The length is impossible.
    Length,
    /// The CRC does not match: damaged, or cut while written.
    Crc,
    /// The commit word is missing: cut before the end of its write.
    NotCommitted,
    /// The body does not decode as a set.
    Decode,
    /// The set is not a valid one ([`FlightStack::check_config`]).
    Invalid,
    /// The flash could not be read.
    Read,
}

/// What went wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The set to save is not valid (the field that failed).
    Invalid(&'static str),
    /// The set does not fit [`MAX_BODY`].
    TooLarge,
    /// The slots are not whole erase sectors within the flash, are smaller than a header and [`MAX_BODY`], or
    /// the flash's write size does not divide 4.
    Layout,
    /// The flash refused an erase or a write.
    Flash,
}

/// Where a loaded set came from, and what was wrong with each slot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LoadReport {
    /// The slot the set came from (`None`: neither held a valid set).
    pub slot: Option<usize>,
    /// Its sequence number.
    pub sequence: u32,
    /// Each slot's problem, if any.
    pub problems: [Option<SlotProblem>; 2],
}

/// The two slots on a flash.
#[derive(Debug)]
pub struct ParamStore<F> {
    flash: F,
    /// Each slot's offset in the flash.
    slots: [u32; 2],
    /// Each slot's size (a multiple of the erase size).
    slot_len: u32,
}

fn le32(b: &[u8]) -> u32 {
    let mut a = [0u8; 4];
    a.copy_from_slice(&b[..4]);
    u32::from_le_bytes(a)
}

impl<F: NorFlash> ParamStore<F> {
    /// A store in two slots of `slot_len` bytes at `slots` (offsets in `flash`).
    pub fn new(flash: F, slots: [u32; 2], slot_len: u32) -> Result<Self, StoreError> {
        let erase = F::ERASE_SIZE as u32;
        let fits = |o: u32| o.is_multiple_of(erase) && o as usize + slot_len as usize <= flash.capacity();
        let apart = slots[0].abs_diff(slots[1]) >= slot_len;
        if !slot_len.is_multiple_of(erase)
            || (slot_len as usize) < HEADER_LEN + MAX_BODY
            || !fits(slots[0])
            || !fits(slots[1])
            || !apart
            || !4usize.is_multiple_of(F::WRITE_SIZE)
        {
            return Err(StoreError::Layout);
        }
        Ok(Self { flash, slots, slot_len })
    }

    /// The flash, given back.
    pub fn into_inner(self) -> F {
        self.flash
    }

    /// A slot's set and sequence, or why there is none.
    fn read_slot(&mut self, k: usize) -> Result<(FlightConfig, u32), SlotProblem> {
        let base = self.slots[k];
        let mut head = [0u8; HEADER_LEN];
        self.flash.read(base, &mut head).map_err(|_| SlotProblem::Read)?;
        if head[0..4] != MAGIC {
            return Err(SlotProblem::Empty);
        }
        if u16::from_le_bytes([head[4], head[5]]) != STORE_FORMAT {
            return Err(SlotProblem::Format);
        }
        let len = u16::from_le_bytes([head[6], head[7]]) as usize;
        if head[8..16] != SCHEMA_KEY {
            return Err(SlotProblem::Schema);
        }
        // A slot holds a header and MAX_BODY at least (checked in `new`).
        if len > MAX_BODY {
            return Err(SlotProblem::Length);
        }
        let mut body = [0u8; MAX_BODY];
        self.flash.read(base + HEADER_LEN as u32, &mut body[..len]).map_err(|_| SlotProblem::Read)?;
        let mut digest = CRC32.digest();
        digest.update(&head[0..20]);
        digest.update(&body[..len]);
        if digest.finalize() != le32(&head[20..24]) {
            return Err(SlotProblem::Crc);
        }
        if le32(&head[24..28]) != COMMIT {
            return Err(SlotProblem::NotCommitted);
        }
        // `take_from_bytes` with nothing left over, as the configuration upload decodes (one decoder in the
        // firmware, not two).
        let p: FlightConfig = match postcard::take_from_bytes(&body[..len]) {
            Ok((p, [])) => p,
            _ => return Err(SlotProblem::Decode),
        };
        FlightStack::check_config(&p).map_err(|_| SlotProblem::Invalid)?;
        Ok((p, le32(&head[16..20])))
    }

    /// The newest valid set (`None` when neither slot holds one: the caller flies its built-in configuration),
    /// with what each slot held.
    pub fn load(&mut self) -> (Option<FlightConfig>, LoadReport) {
        let a = self.read_slot(0);
        let b = self.read_slot(1);
        let problems = [a.as_ref().err().copied(), b.as_ref().err().copied()];
        let best = match (a, b) {
            // Sequence numbers compare as serial numbers (RFC 1982): the newer is ahead by less than half
            // the range, so the count may wrap; a tie (never written so) goes to slot 0.
            (Ok(x), Ok(y)) => Some(if (y.1.wrapping_sub(x.1) as i32) > 0 { (1, y) } else { (0, x) }),
            (Ok(x), Err(_)) => Some((0, x)),
            (Err(_), Ok(y)) => Some((1, y)),
            (Err(_), Err(_)) => None,
        };
        match best {
            Some((slot, (p, sequence))) => (Some(p), LoadReport { slot: Some(slot), sequence, problems }),
            None => (None, LoadReport { slot: None, sequence: 0, problems }),
        }
    }

    /// Saves `p` (validated first) in the slot that does not hold the newest valid set; returns its sequence
    /// number. The newest set stays valid until the new one's commit word is written.
    pub fn save(&mut self, p: &FlightConfig) -> Result<u32, StoreError> {
        FlightStack::check_config(p).map_err(|e| StoreError::Invalid(e.field))?;
        let mut body = [0u8; MAX_BODY];
        // A set larger than MAX_BODY does not serialise into it: the slot, at least a header and MAX_BODY, holds it.
        let len = postcard::to_slice(p, &mut body).map_err(|_| StoreError::TooLarge)?.len();
        let (_, report) = self.load();
        let (target, sequence) = match report.slot {
            Some(k) => (1 - k, report.sequence.wrapping_add(1)),
            None => (0, 1),
        };
        let base = self.slots[target];
        self.flash.erase(base, base + self.slot_len).map_err(|_| StoreError::Flash)?;
        let mut head = [0u8; HEADER_LEN];
        head[0..4].copy_from_slice(&MAGIC);
        head[4..6].copy_from_slice(&STORE_FORMAT.to_le_bytes());
        head[6..8].copy_from_slice(&(len as u16).to_le_bytes());
        head[8..16].copy_from_slice(&SCHEMA_KEY);
        head[16..20].copy_from_slice(&sequence.to_le_bytes());
        let mut digest = CRC32.digest();
        digest.update(&head[0..20]);
        digest.update(&body[..len]);
        head[20..24].copy_from_slice(&digest.finalize().to_le_bytes());
        // Everything but the commit word (left erased), the body padded to the write size with erased bytes.
        let padded = len.next_multiple_of(4);
        body[len..padded].fill(0xFF);
        self.flash.write(base, &head[..24]).map_err(|_| StoreError::Flash)?;
        self.flash.write(base + HEADER_LEN as u32, &body[..padded]).map_err(|_| StoreError::Flash)?;
        self.flash.write(base + 24, &COMMIT.to_le_bytes()).map_err(|_| StoreError::Flash)?;
        Ok(sequence)
    }
}

#[cfg(test)]
mod tests;
