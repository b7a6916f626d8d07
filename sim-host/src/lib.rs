//! Host side of the wall-line quadrotor: scenarios, camera renderers, the ground station's vision, and the
//! command-line tool `sim-host`.
#![warn(missing_docs)]

pub mod imageio;
pub mod model;
pub mod render;
pub mod rng;
pub mod scenario;
pub mod sensors;
pub mod sil;
pub mod vision;

pub use scenario::Scenario;
