//! Host side of the wall-line quadrotor: scenarios, camera renderers, the ground station's vision, and the
//! command-line tool `sim-host`.
#![warn(missing_docs)]
// Index loops read naturally in small dense numerics; `!(x > 0.0)` deliberately rejects NaN.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

pub mod camera_worker;
pub mod downward;
pub mod export;
pub mod fil;
pub mod foxglove_msgs;
/// The flight log and atomic file writes live in their own crate, re-exported under their old paths.
pub use flightlog::{self, files};
pub mod fly;
pub mod imageio;
pub mod import;
pub mod link_key;
#[cfg(feature = "live")]
pub mod live;
pub mod live_rate;
pub mod mavlink_endpoint;
pub use vehicle_model as model;
pub mod params_doc;
pub mod plot;
pub mod power;
pub mod reference;
pub mod render;
pub mod replay;
pub mod rng;
pub mod scenario;
pub mod sensors;
pub mod sil;
pub mod station;
pub mod sweep;
pub mod transmitter;
pub mod virtual_vehicle;
pub mod vision;
pub mod wind;

pub use scenario::Scenario;
