//! The shared volume-rendering crate under the `nerf` and `nsff` crates.
//!
//! - geometry (re-exported from `nerf-data`): [`camera`], [`rays`], [`ndc`]
//! - samplers: where to look along a ray ([`sampler`]), and the [`occupancy`] grid that lets the
//!   marcher skip empty space, per time bin for fields that change with time ([`timed_occupancy`])
//! - which pixels to train on: [`error_map`], draws in proportion to the recent training error
//! - fields: the [`field::Field`] trait every model's fields implement
//! - renderers: [`render::render`] turns samples and field outputs into pixels, through the fused
//!   kernel in [`composite`]
//! - fields' building blocks: [`encoding`] (positional, hash grid, spherical harmonics)
//! - [`host_op`]: fused CPU kernels with hand-written backward passes, usable as burn ops
//! - [`metrics`]: PSNR and SSIM

pub mod composite;
pub mod device;
pub mod encoding;
pub mod error_map;
pub mod field;
pub mod host_op;
pub mod metrics;
pub mod mlp;
pub mod occupancy;
pub mod optim;
pub mod profile;
pub mod readback;
pub mod render;
pub mod sampler;
pub mod timed_occupancy;

pub use nerf_data::{camera, ndc, rays};
