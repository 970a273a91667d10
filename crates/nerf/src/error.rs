//! Errors of the model side: checkpoints that do not fit, devices that cannot be used, tensors
//! that cannot be read back, and the data errors beneath them. Every variant says which file or
//! which thing failed.

use std::path::{Path, PathBuf};

use burn::tensor::Tensor;
use nerf_data::DataError;

pub use nerf_core::readback::ReadBackError;

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// Reading the dataset or writing outputs.
    #[error(transparent)]
    Data(#[from] DataError),
    /// A checkpoint that is missing, corrupt or does not match its configuration.
    #[error("{}: {msg}", path.display())]
    Checkpoint { path: PathBuf, msg: String },
    #[error(transparent)]
    ReadBack(#[from] ReadBackError),
    /// The `--device` name or the device itself.
    #[error("device '{name}': {msg}")]
    Device { name: String, msg: String },
    /// A command line that cannot be carried out (names the file or folder it is about).
    #[error("{}: {msg}", path.display())]
    Usage { path: PathBuf, msg: String },
}

impl ModelError {
    pub fn checkpoint(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        ModelError::Checkpoint {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }

    pub fn usage(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        ModelError::Usage {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }
}

pub type Result<T, E = ModelError> = std::result::Result<T, E>;

/// A tensor's values on the host, or [`ModelError::ReadBack`].
pub fn read_back<const D: usize>(t: Tensor<D>, what: &'static str) -> Result<Vec<f32>, ModelError> {
    Ok(nerf_core::readback::read_back(t, what)?)
}

/// A one-element tensor's value on the host.
pub fn read_scalar(t: Tensor<1>, what: &'static str) -> Result<f64, ModelError> {
    let v = read_back(t, what)?;
    v.first()
        .map(|&x| x as f64)
        .ok_or(ModelError::ReadBack(ReadBackError {
            what,
            msg: "empty tensor".into(),
        }))
}
