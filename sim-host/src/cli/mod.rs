//! The commands, one module each.
pub(crate) mod common;
pub(crate) mod configure;
pub(crate) mod export;
pub(crate) mod fly;
pub(crate) mod import;
pub(crate) mod render;
pub(crate) mod replay;
pub(crate) mod station;
pub(crate) mod sweep;
pub(crate) mod vision;
