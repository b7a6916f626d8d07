//! Vision for the wall-line quadrotor, `no_std` and without allocation.
//!
//! - [`image`]: borrowed RGB8 and grey views with a stride.
//! - [`camera`]: pinhole intrinsics with Brown-Conrady distortion.
//! - [`target`]: the painted line's rectangle and its corners `A, B, C, D` (paper Fig. 1).
//! - [`tone`]: the camera's tone curve (sRGB or linear), undone before edges are measured.
//! - [`detect`]: red-line segmentation, sub-pixel edges and robust line fits, giving a [`LineObservation`].
//! - [`pose`]: vanishing points and least-squares pose (paper eq. 1-14), image-only or IMU-aided, refined by
//!   minimising the reprojection error, with the planar ambiguity resolved by gravity.
//!
//! Time never enters this crate: callers attach timestamps to what they pass on.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic))]
// Index loops read naturally in small dense linear algebra; `!(x > 0.0)` deliberately rejects NaN.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

pub mod camera;
pub mod detect;
pub mod flow;
pub mod image;
pub mod observation;
pub mod pose;
pub mod target;
pub mod tone;

pub use camera::{CameraModel, Distortion};
pub use detect::{
    DetectionDiagnostics, DetectorParams, DetectorWorkspace, NoTargetReason, RowTiming, detect_line,
    detect_line_timed,
};
pub use image::{Gray8View, Rgb8View};
pub use observation::{EdgeStats, LineObservation};
pub use pose::{
    AttitudeSource, CameraMount, PoseError, PoseParams, PoseSolution, TranslationMethod, solve_pose,
};
pub use target::{Corner, Edge, LineTarget};
pub use tone::ToneCurve;
