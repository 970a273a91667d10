//! Static NeRF: fields, the rendering pipeline, training, evaluation and rendering.

pub mod checkpoint;
pub mod cli;
pub mod config;
pub mod eval;
pub mod field;
pub mod logging;
pub mod model;
pub mod plot;
pub mod render;
pub mod renderer;
pub mod train_loop;
pub mod trainer;
