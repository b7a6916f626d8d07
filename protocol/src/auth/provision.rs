//! The vehicle's key as the debug probe writes it into flash (docs/security.md, "Provisioning a board").
//!
//! The key never travels over the radio: `sim-host key-image --key FILE --out key.bin` turns the station's key
//! file into this block, and the probe writes it at [`KEY_BLOCK_ADDRESS`] (`probe-rs download --binary-format
//! bin --base-address 0x080E0000 key.bin`). The firmware reads it at boot; an erased sector (all 0xFF) means
//! no key: the development mode, in which the vehicle refuses to arm unless built with the
//! `unauthenticated-link` feature.
//!
//! ```text
//! block = "WLQK" format(1) 0 0 0 key(32) check(8)     48 bytes
//! check = the first 8 bytes of SHA-256("WLQK" format 0 0 0 key)
//! ```
//!
//! The check refuses a block half written or damaged, never a usable key taken wrong: a bit flipped in the
//! key would make every frame fail its tag, and this names the cause instead.
use sha2::{Digest, Sha256};

use super::{KEY_LEN, Key};

/// Where the block lives: the first bytes of the STM32F405's last flash sector (sector 11, 128 KB), which the
/// firmware's linker script leaves out of its flash region, so that flashing a new firmware keeps the key.
pub const KEY_BLOCK_ADDRESS: u32 = 0x080E_0000;
/// Length of the block (bytes).
pub const KEY_BLOCK_LEN: usize = 48;
/// The block's format.
pub const KEY_BLOCK_FORMAT: u8 = 1;
const MAGIC: &[u8; 4] = b"WLQK";

/// Why a block holds no key.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum KeyBlockError {
    /// All 0xFF: nothing was ever written (the development mode).
    Erased,
    /// The first 4 bytes are not "WLQK": something else is in the sector.
    NotAKeyBlock,
    /// Another format than [`KEY_BLOCK_FORMAT`] (the byte found).
    UnknownFormat(u8),
    /// The check does not match: a block half written or damaged.
    BadCheck,
    /// Shorter than [`KEY_BLOCK_LEN`].
    Short,
}

fn check(head_and_key: &[u8]) -> [u8; 8] {
    let d = Sha256::digest(head_and_key);
    let mut c = [0u8; 8];
    c.copy_from_slice(&d[..8]);
    c
}

/// The block that provisions `key`.
pub fn key_block(key: &Key) -> [u8; KEY_BLOCK_LEN] {
    let mut b = [0u8; KEY_BLOCK_LEN];
    b[..4].copy_from_slice(MAGIC);
    b[4] = KEY_BLOCK_FORMAT;
    b[8..8 + KEY_LEN].copy_from_slice(key);
    let c = check(&b[..8 + KEY_LEN]);
    b[8 + KEY_LEN..].copy_from_slice(&c);
    b
}

/// The key a block holds (the first [`KEY_BLOCK_LEN`] bytes of `flash` are read).
pub fn read_key_block(flash: &[u8]) -> Result<Key, KeyBlockError> {
    let b = flash.get(..KEY_BLOCK_LEN).ok_or(KeyBlockError::Short)?;
    if b.iter().all(|&x| x == 0xFF) {
        return Err(KeyBlockError::Erased);
    }
    if &b[..4] != MAGIC {
        return Err(KeyBlockError::NotAKeyBlock);
    }
    if b[4] != KEY_BLOCK_FORMAT {
        return Err(KeyBlockError::UnknownFormat(b[4]));
    }
    if b[5..8] != [0, 0, 0] || b[8 + KEY_LEN..] != check(&b[..8 + KEY_LEN]) {
        return Err(KeyBlockError::BadCheck);
    }
    let mut key = [0u8; KEY_LEN];
    key.copy_from_slice(&b[8..8 + KEY_LEN]);
    Ok(key)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_block_gives_back_its_key_and_every_damage_is_named() {
        let key: Key = core::array::from_fn(|i| (i as u8).wrapping_mul(37) ^ 0xA5);
        let b = key_block(&key);
        assert_eq!(read_key_block(&b), Ok(key));
        // Trailing flash after the block is not read.
        let mut sector = [0xFFu8; 64];
        sector[..KEY_BLOCK_LEN].copy_from_slice(&b);
        assert_eq!(read_key_block(&sector), Ok(key));
        assert_eq!(read_key_block(&[0xFF; KEY_BLOCK_LEN]), Err(KeyBlockError::Erased));
        assert_eq!(read_key_block(&b[..KEY_BLOCK_LEN - 1]), Err(KeyBlockError::Short));
        // Every single bit flipped anywhere in the block is refused, none gives another key.
        for i in 0..KEY_BLOCK_LEN * 8 {
            let mut d = b;
            d[i / 8] ^= 1 << (i % 8);
            let r = read_key_block(&d);
            assert!(r.is_err(), "bit {i}: {r:?}");
            let want = match i / 8 {
                0..4 => KeyBlockError::NotAKeyBlock,
                4 => KeyBlockError::UnknownFormat(d[4]),
                _ => KeyBlockError::BadCheck,
            };
            assert_eq!(r, Err(want), "bit {i}");
        }
        // A block written half (the rest still erased).
        let mut half = [0xFFu8; KEY_BLOCK_LEN];
        half[..24].copy_from_slice(&b[..24]);
        assert_eq!(read_key_block(&half), Err(KeyBlockError::BadCheck));
    }

    #[test]
    fn golden_bytes_of_a_block() {
        // Pinned (docs/security.md): the layout and the check of the zero key.
        let b = key_block(&[0; KEY_LEN]);
        assert_eq!(b[..8], *b"WLQK\x01\x00\x00\x00");
        assert_eq!(b[8..40], [0; 32]);
        // SHA-256 of those 40 bytes, computed apart (Python's hashlib), first 8 bytes.
        assert_eq!(b[40..], [0x97, 0x6d, 0x71, 0x2e, 0x70, 0xcc, 0xf3, 0xa7]);
    }
}
