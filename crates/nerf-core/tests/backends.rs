//! Cross-backend check: the fused ops give the same values and gradients on burn-ndarray as on
//! burn-flex (the default backend). Both are compiled in by default.
#![cfg(all(feature = "flex", feature = "ndarray"))]
#![allow(deprecated)]

use std::sync::Arc;

use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::composite::{RayLayout, composite};
use nerf_core::encoding::{HashGrid, HashGridConfig};
use rand::{Rng, SeedableRng, rngs::StdRng};

fn host(t: Tensor<2>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().unwrap()
}

fn run(device: &Device) -> Vec<Vec<f32>> {
    let mut rng = StdRng::seed_from_u64(1);
    let (r, s) = (16usize, 12usize);
    let sigma: Vec<f32> = (0..r * s).map(|_| rng.random_range(0.0..4.0)).collect();
    let rgb: Vec<f32> = (0..r * s * 3).map(|_| rng.random_range(0.0..1.0)).collect();
    let layout = RayLayout {
        offsets: Arc::new((0..=r as u32).map(|i| i * s as u32).collect()),
        deltas: Arc::new((0..r * s).map(|_| rng.random_range(0.0..0.3)).collect()),
    };
    let ts = Tensor::<2>::from_data(TensorData::new(sigma, [r * s, 1]), device).require_grad();
    let tc = Tensor::<2>::from_data(TensorData::new(rgb, [r * s, 3]), device).require_grad();
    let out = composite(ts.clone(), tc.clone(), None, &layout, 0.0);
    let grid = HashGrid::new(
        HashGridConfig {
            dims: 3,
            levels: 4,
            features: 2,
            log2_table: 10,
            base_resolution: 4,
            finest_resolution: 32,
            time_resolution: None,
            time_follows_space: false,
        },
        7,
    );
    let pts: Vec<f32> = (0..60).map(|_| rng.random_range(0.0..1.0)).collect();
    let x = Tensor::<2>::from_data(TensorData::new(pts, [20, 3]), device).require_grad();
    let feats = grid.encode(x.clone());
    let loss = (out.clone() * out.clone()).sum() + (feats.clone() * feats.clone()).sum();
    let g = loss.backward();
    vec![
        host(out.inner()),
        host(ts.grad(&g).unwrap()),
        host(tc.grad(&g).unwrap()),
        host(feats.inner()),
        host(x.grad(&g).unwrap()),
        grid.grad(),
    ]
}

#[test]
fn flex_and_ndarray_agree() {
    let a = run(&Device::flex().autodiff());
    let b = run(&Device::ndarray().autodiff());
    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
        assert_eq!(x.len(), y.len());
        for (p, q) in x.iter().zip(y) {
            assert!((p - q).abs() <= 1e-5 * (1.0 + p.abs()), "output {k}: {p} vs {q}");
        }
    }
}
