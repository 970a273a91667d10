//! Loss helpers (NSFF's weighted means: Σ m·err / (Σ m·C + 1e-8), the mask broadcast over the
//! C channels).

use burn::tensor::Tensor;

pub fn mse(a: Tensor<2>, b: Tensor<2>) -> Tensor<1> {
    (a - b).powi_scalar(2).mean()
}

/// Mask-weighted mean squared error; `mask` is `[N, 1]`.
pub fn wmse(a: Tensor<2>, b: Tensor<2>, mask: Tensor<2>) -> Tensor<1> {
    let c = a.dims()[1] as f32;
    let err = (a - b).powi_scalar(2) * mask.clone();
    err.sum() / (mask.sum() * c + 1e-8)
}

/// Mask-weighted mean absolute error; `mask` is `[N, 1]`.
pub fn wmae(a: Tensor<2>, b: Tensor<2>, mask: Tensor<2>) -> Tensor<1> {
    let c = a.dims()[1] as f32;
    let err = (a - b).abs() * mask.clone();
    err.sum() / (mask.sum() * c + 1e-8)
}

/// One-sided entropy −b·log(b + 1e-8), averaged: pushes blend weights towards 0 or 1.
pub fn entropy(b: Tensor<2>) -> Tensor<1> {
    (b.clone() * (b + 1e-8).log()).neg().mean()
}
