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

/// A `[N, C]` tensor's values where a failed read-back is a bug (tests, diagnostics): panics
/// with the error.
pub fn host(t: Tensor<2>) -> Vec<f32> {
    read_back(t, "tensor").unwrap_or_else(|e| panic!("{e}"))
}

/// Panics unless `a` and `b` have the same length and differ by at most `tol` everywhere
/// (tests comparing two render paths).
pub fn assert_close(what: &str, a: &[f32], b: &[f32], tol: f32) {
    assert_eq!(a.len(), b.len(), "{what}: lengths differ");
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert!((x - y).abs() <= tol, "{what}[{i}]: {x} vs {y}");
    }
}
