//! Camera renderers: the source of truth for the vision tests and the simulator's cameras.
pub mod down;
pub mod forward;
mod lens;
pub mod polygon;
mod sensor;
pub mod texture;

pub use down::{DownPose, DownRenderer, DownSettings};
pub use forward::{ForwardRenderer, RenderSettings};
