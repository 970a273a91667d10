//! Static NeRF: fields (`field/`), sampling and the model (`renderer.rs`, `model.rs`), the
//! optimiser step and checkpoints every model shares (`optimizer.rs`, `checkpoint.rs`), training
//! (`trainer.rs`, `train_loop.rs`), evaluation (`eval.rs`; `diagnosis.rs` for generated scenes), render
//! paths (`render.rs`) and the CLI.

pub mod checkpoint;
pub mod cli;
pub mod config;
pub mod diagnosis;
pub mod error;
pub mod eval;
pub mod export;
pub mod field;
pub mod logging;
pub mod model;
pub mod optimizer;
pub mod plot;
pub mod render;
pub mod renderer;
pub mod train_loop;
pub mod trainer;
pub mod viewer;
