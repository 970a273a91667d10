//! Scene inputs for the NeRF and NSFF crates: cameras, rays, images and one parser per format.
//!
//! This crate has no burn dependency, so the parsers build and test in seconds; `nerf-core`
//! re-exports the geometry modules as part of the shared rendering crate. The synthetic scene
//! generator (`nerf-synth`) and the optical-flow estimators (`nerf-flow`) build on it.

pub mod blender;
pub mod camera;
pub mod colmap;
pub mod dataset;
pub mod error;
pub mod image;
pub mod llff;
pub mod load;
pub mod mask;
pub mod math;
pub mod ndc;
pub mod npy;
pub mod npz;
pub mod options;
pub mod rays;
pub mod tiny_npz;
pub mod video;

pub use camera::{AxisConvention, Camera, Intrinsics, Pose};
pub use dataset::{Dataset, FlowField, Format, RayBatch, SceneKind, VideoPriors, View};
pub use error::{DataError, Result};
pub use image::Image;
pub use ndc::Ndc;
pub use options::{LoadOptions, NDC_MAX_VIEW_ANGLE_DEG, NdcMode};
pub use rays::Rays;

/// The shared real datasets (`../shared/data` beside the project root), or `None` when absent.
/// `NERF_SHARED_DATA` overrides the location. Tests and benches skip with a message when absent.
pub fn shared_data() -> Option<std::path::PathBuf> {
    if let Some(p) = std::env::var_os("NERF_SHARED_DATA") {
        return Some(p.into());
    }
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    root.is_dir().then(|| root.canonicalize().unwrap_or(root))
}
