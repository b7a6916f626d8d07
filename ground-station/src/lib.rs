//! The ground station of the wall-line quadrotor (std).
//!
//! In the paper's setup the vision runs on a ground PC that receives both cameras' images and sends its
//! measurements to the vehicle over a serial radio. Everything the vehicle is sent carries times on the
//! *vehicle's* clock, so the station first needs to know that clock: [`clock`].
#![warn(missing_docs)]

pub mod calib;
pub mod clock;
pub mod console;
pub mod link;
pub mod mavlink_bridge;
pub mod operator;
pub mod source;
pub mod stream;
pub mod v4l2;
pub mod vision;
