//! The radio link's downlink side: frames a message and queues it for the UART.
use crate::board::Board;
use protocol::frame::{MAX_FRAME, encode};

/// Frames `msg` and queues it; a message that does not fit the queue whole is dropped (never half-sent).
pub fn send<T: serde::Serialize>(board: &mut Board, msg: &T) {
    let mut buf = [0u8; MAX_FRAME];
    if let Ok(frame) = encode(msg, &mut buf) {
        let n = frame.len();
        let mut tmp = [0u8; MAX_FRAME];
        tmp[..n].copy_from_slice(frame);
        if board.tx_free() >= n {
            board.tx_bytes(&tmp[..n]);
        }
    }
}
