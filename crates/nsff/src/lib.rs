//! Neural Scene Flow Fields: a static field plus a time-conditioned dynamic field with 3-D scene
//! flow and disocclusion weights, trained from one moving camera's video. Reuses the static
//! pipeline (`nerf`): its fields, compositing, trainer bookkeeping and renders.

pub mod config;
pub mod eval;
pub mod geometry;
pub mod losses;
pub mod model;
pub mod render;
pub mod trainer;
pub mod video;
