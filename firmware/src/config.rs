//! The flight configuration: loaded from flash at boot, replaced by an upload over the link on the ground, and
//! stored again (`flight_core::param_store`, `flight_core::config_upload`; docs/firmware.md, "Parameters in
//! flash").
//!
//! - On the board the store is two 128 KB flash sectors, 9 and 10 (0x080A0000 and 0x080C0000), which the linker
//!   script leaves out of the program (`memory.x`), through the HAL's flash driver. Erasing a sector takes about
//!   a second, during which the core stalls on every fetch from flash: the control loop misses its ticks, so a
//!   set is stored only while disarmed (an upload is refused otherwise).
//! - Under QEMU, whose STM32F405 model has no flash controller (its flash is read-only memory), the store is
//!   4 KB of RAM with the same NOR semantics: the firmware in the loop exercises the same code, and a set lasts
//!   until QEMU exits.
use flight_core::param_store::{LoadReport, ParamStore};
use flight_core::{FlightConfig, FlightStack};
use protocol::{ConfigAck, ConfigChunk, ConfigOutcome};

/// The configuration at boot: the stored one, or the built-in one (the paper's) when the store holds none,
/// with what the store said.
pub fn at_boot(store: &mut Option<ParamStore<Flash>>) -> (FlightConfig, Option<LoadReport>) {
    let Some(store) = store.as_mut() else { return (FlightConfig::paper(), None) };
    let (cfg, report) = store.load();
    (cfg.unwrap_or_else(FlightConfig::paper), Some(report))
}

/// The store on this board's flash, or `None` (said in the log) when its layout does not fit.
pub fn store(flash: Flash) -> Option<ParamStore<Flash>> {
    match ParamStore::new(flash, SLOTS, SLOT_LEN) {
        Ok(s) => Some(s),
        Err(e) => {
            defmt::error!("parameter store: {}", e);
            None
        }
    }
}

/// Takes an upload's piece; when the upload is whole, rebuilds `stack` from it (disarmed only), stores it,
/// and returns the answer for the station. `on_new` sees the new configuration before the stack runs on it (the
/// background work's copy of the vision configuration).
pub fn take_piece(
    upload: &mut flight_core::config_upload::ConfigUpload,
    chunk: &ConfigChunk,
    stack: &mut FlightStack,
    store: &mut Option<ParamStore<Flash>>,
    on_new: impl FnOnce(&FlightConfig),
) -> Option<ConfigAck> {
    let (crc32, result) = upload.push(chunk)?;
    let outcome = match flight_core::config_upload::take_when_disarmed(result, stack.control().mode()) {
        Err(r) => ConfigOutcome::Refused(r),
        Ok(cfg) => {
            on_new(&cfg);
            rebuild(stack, cfg);
            let saved = match store.as_mut().map(|s| s.save(&cfg)) {
                Some(Ok(seq)) => Some(seq),
                Some(Err(e)) => {
                    defmt::error!("the uploaded configuration runs but could not be stored: {}", e);
                    None
                }
                None => None,
            };
            ConfigOutcome::Applied { saved_sequence: saved }
        }
    };
    Some(ConfigAck { crc32, outcome })
}

/// The flight stack rebuilt from `cfg`. Not inlined: the new stack (21 KB) is built on the stack and moved into
/// place, and that space is needed only while this runs (on the ground, after an upload), not in the frame of
/// every control step that might call it.
#[inline(never)]
fn rebuild(stack: &mut FlightStack, cfg: FlightConfig) {
    *stack = FlightStack::new_checked(cfg);
}

#[cfg(not(feature = "qemu"))]
mod flash {
    use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
    use stm32f4xx_hal::flash::{Error, FlashExt, LockedFlash};

    /// The store's two slots: flash sectors 9 and 10 (offsets from the start of flash).
    pub const SLOTS: [u32; 2] = [0x000A_0000, 0x000C_0000];
    /// A slot: one 128 KB sector.
    pub const SLOT_LEN: u32 = 128 * 1024;

    /// The on-chip flash, unlocked for each erase or write only.
    pub struct Flash(pub LockedFlash);

    impl ErrorType for Flash {
        type Error = Error;
    }

    impl ReadNorFlash for Flash {
        const READ_SIZE: usize = 1;

        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
            ReadNorFlash::read(&mut self.0, offset, bytes)
        }

        fn capacity(&self) -> usize {
            ReadNorFlash::capacity(&self.0)
        }
    }

    impl NorFlash for Flash {
        const WRITE_SIZE: usize = 1;
        const ERASE_SIZE: usize = 128 * 1024;

        fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
            NorFlash::erase(&mut self.0.unlocked(), from, to)
        }

        fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
            NorFlash::write(&mut self.0.unlocked(), offset, bytes)
        }
    }
}

#[cfg(feature = "qemu")]
mod flash {
    use embedded_storage::nor_flash::{ErrorType, NorFlash, NorFlashErrorKind, ReadNorFlash};

    /// A slot: one 2 KB "sector" of the RAM store (a header and the largest set fit).
    pub const SLOT_LEN: u32 = 2048;
    /// The store's two slots.
    pub const SLOTS: [u32; 2] = [0, SLOT_LEN];

    /// QEMU's stand-in for the flash: RAM that erases to 0xFF and whose writes can only clear bits, as NOR
    /// flash does.
    pub struct Flash(pub [u8; 2 * SLOT_LEN as usize]);

    impl Flash {
        /// Erased.
        pub const fn new() -> Self {
            Self([0xFF; 2 * SLOT_LEN as usize])
        }

        fn range(&self, offset: u32, len: usize) -> Result<core::ops::Range<usize>, NorFlashErrorKind> {
            let start = offset as usize;
            (start + len <= self.0.len()).then_some(start..start + len).ok_or(NorFlashErrorKind::OutOfBounds)
        }
    }

    impl ErrorType for Flash {
        type Error = NorFlashErrorKind;
    }

    impl ReadNorFlash for Flash {
        const READ_SIZE: usize = 1;

        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
            let r = self.range(offset, bytes.len())?;
            bytes.copy_from_slice(&self.0[r]);
            Ok(())
        }

        fn capacity(&self) -> usize {
            self.0.len()
        }
    }

    impl NorFlash for Flash {
        const WRITE_SIZE: usize = 1;
        const ERASE_SIZE: usize = SLOT_LEN as usize;

        fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
            if !(from as usize).is_multiple_of(Self::ERASE_SIZE)
                || !(to as usize).is_multiple_of(Self::ERASE_SIZE)
            {
                return Err(NorFlashErrorKind::NotAligned);
            }
            let r = self.range(from, to.saturating_sub(from) as usize)?;
            self.0[r].fill(0xFF);
            Ok(())
        }

        fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
            let r = self.range(offset, bytes.len())?;
            for (m, b) in self.0[r].iter_mut().zip(bytes) {
                *m &= *b;
            }
            Ok(())
        }
    }
}

pub use flash::{Flash, SLOT_LEN, SLOTS};

/// What the store said, for the boot log.
pub fn describe(report: &Option<LoadReport>) -> &'static str {
    match report {
        None => "no parameter store: the built-in configuration",
        Some(LoadReport { slot: Some(_), .. }) => "the stored configuration",
        Some(LoadReport { slot: None, .. }) => "nothing stored: the built-in configuration",
    }
}
