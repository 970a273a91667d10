//! Reading tensors back to the host. A failed read-back (a device error, an unexpected dtype) is
//! an error the caller reports, never an empty vector that silently renders black.

use burn::tensor::Tensor;

/// A tensor could not be read back from its device.
#[derive(Debug, thiserror::Error)]
#[error("reading {what} back from the device failed: {msg}")]
pub struct ReadBackError {
    pub what: &'static str,
    pub msg: String,
}

/// The values of any float tensor as `f32`, row-major; `what` names it in the error.
pub fn read_back<const D: usize>(t: Tensor<D>, what: &'static str) -> Result<Vec<f32>, ReadBackError> {
    t.into_data().try_into_vec_as::<f32>().map_err(|e| ReadBackError {
        what,
        msg: format!("{e:?}"),
    })
}
