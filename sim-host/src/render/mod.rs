//! Camera renderers: the source of truth for the vision tests and the simulator's cameras.
pub mod forward;
pub mod polygon;
pub mod texture;

pub use forward::{ForwardRenderer, RenderSettings};
