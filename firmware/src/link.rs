//! The radio link's downlink side: frames a message through the vehicle's radio (`flight_core::radio`: sealed
//! when keyed) and queues it for the UART.
use crate::board::Board;
use flight_core::radio::VehicleRadio;
use protocol::Downlink;
use protocol::frame::MAX_FRAME;
#[cfg(feature = "fil")]
use protocol::frame::encode;

/// Frames `msg` and queues it. Counted and not sent: a message before a keyed session or unframable
/// (`VehicleRadio::not_sent`), or one that does not fit the queue whole (never half-sent; `RunStats`).
pub fn send(board: &mut Board, radio: &mut VehicleRadio, msg: &Downlink) -> bool {
    let mut buf = [0u8; MAX_FRAME];
    match radio.frame(msg, &mut buf) {
        Ok(frame) => send_frame(board, frame),
        Err(_) => true,
    }
}

/// Queues a complete frame if it fits whole; false when it did not.
pub fn send_frame(board: &mut Board, frame: &[u8]) -> bool {
    if board.tx_free() >= frame.len() {
        board.tx_bytes(frame);
        true
    } else {
        false
    }
}

/// Frames `msg` unauthenticated and queues it (the firmware-in-the-loop protocol, `flight_core::fil`, whose
/// wire is QEMU's emulated UART, not a radio); a message that does not fit the queue whole is dropped.
#[cfg(feature = "fil")]
pub fn send_plain<T: serde::Serialize>(board: &mut Board, msg: &T) {
    let mut buf = [0u8; MAX_FRAME];
    if let Ok(frame) = encode(msg, &mut buf) {
        send_frame(board, frame);
    }
}
