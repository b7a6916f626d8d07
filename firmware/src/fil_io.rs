//! The firmware in the loop's wire to the simulator: two named pipes on the host, read and written through
//! QEMU's semihosting (`SYS_OPEN`, `SYS_READ`, `SYS_WRITE`), a block of bytes per call.
//!
//! QEMU's UART model takes one byte per turn of its main loop, which held the lockstep to a third of real time
//! (0.1 on a slower host): a step's sensors and report are about 370 bytes. A semihosting call moves a whole
//! block and, under `-icount`, costs the guest no virtual time while the host is busy, so the steps' costs stay
//! exact. The simulator makes the pipes `fil-to-fc` and `fil-from-fc` in QEMU's working directory
//! (`sim_host::fil`); the board never builds this variant.
use cortex_m_semihosting::nr;

/// The pipe the simulator writes (steps, radio messages) and the one it reads (reports).
const TO_FC: &[u8] = b"fil-to-fc\0";
const FROM_FC: &[u8] = b"fil-from-fc\0";

/// The two open pipes.
pub struct FilIo {
    rx: usize,
    tx: usize,
    /// Bytes the simulator could not be sent (a write that failed: the simulator has gone).
    pub write_errors: u32,
}

/// `SYS_OPEN` of a NUL-terminated name; `None` when the host refused.
fn open(name: &[u8], mode: usize) -> Option<usize> {
    #[allow(unsafe_code)]
    // SAFETY: a semihosting call with a valid NUL-terminated name and its length without the NUL.
    let fd = unsafe { cortex_m_semihosting::syscall!(OPEN, name.as_ptr(), mode, name.len() - 1) } as isize;
    (fd >= 0).then_some(fd as usize)
}

impl FilIo {
    /// Opens both pipes (the simulator keeps both ends open, so neither open blocks); `None` when the host has
    /// no such files (QEMU started by hand, not by the simulator).
    pub fn open() -> Option<Self> {
        Some(Self {
            rx: open(TO_FC, nr::open::R_BINARY)?,
            tx: open(FROM_FC, nr::open::W_TRUNC_BINARY)?,
            write_errors: 0,
        })
    }

    /// Reads what the simulator has sent, at least one byte (the call blocks until then); 0 when the simulator
    /// closed its end.
    pub fn read(&mut self, buf: &mut [u8]) -> usize {
        #[allow(unsafe_code)]
        // SAFETY: a semihosting read into a buffer we own, of its length.
        let not_read = unsafe { cortex_m_semihosting::syscall!(READ, self.rx, buf.as_mut_ptr(), buf.len()) };
        // SYS_READ answers the count it did not read (the whole length at the end of the file).
        buf.len().saturating_sub(not_read)
    }

    /// Writes all of `bytes`.
    pub fn write(&mut self, mut bytes: &[u8]) {
        while !bytes.is_empty() {
            #[allow(unsafe_code)]
            // SAFETY: a semihosting write of a buffer we own, of its length.
            let not_written =
                unsafe { cortex_m_semihosting::syscall!(WRITE, self.tx, bytes.as_ptr(), bytes.len()) };
            if not_written >= bytes.len() {
                self.write_errors = self.write_errors.saturating_add(1);
                return;
            }
            bytes = &bytes[bytes.len() - not_written..];
        }
    }
}
