//! The radio link's downlink side: frames a message through the vehicle's radio (`flight_core::radio`: sealed
//! when keyed) and queues it for the UART.
use crate::board::Board;
use flight_core::radio::VehicleRadio;
use protocol::Downlink;
use protocol::frame::MAX_FRAME;

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
