//! Neural Scene Flow Fields: a static field plus a time-conditioned dynamic field with 3-D scene
//! flow and disocclusion weights, trained from one moving camera's video. Reuses the static
//! pipeline (`nerf`): its fields, the shared render function, optimiser step, checkpoint parts,
//! training loop and evaluation. `field.rs` defines the two fields, `model.rs` the model,
//! `render.rs` space-time rendering, `losses.rs` the loss terms, `trainer.rs` the training step.

pub mod capture;
pub mod checkpoint;
pub mod config;
pub mod eval;
pub mod export;
pub mod field;
pub mod geometry;
pub mod losses;
pub mod model;
pub mod render;
pub mod trainer;
pub mod video;
pub mod view;
