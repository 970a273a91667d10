//! Differentiable geometry on burn tensors: NDC → Euclidean, and projection into a camera.

use burn::tensor::{Device, Tensor};
use nerf_data::{Camera, Ndc};

/// `[N, 3]` NDC points to world points (NSFF's E), with z_ndc clamped to [−1, 0.99] because the
/// map diverges at z_ndc = 1.
pub fn ndc_to_world(p: Tensor<2>, ndc: &Ndc) -> Tensor<2> {
    let n = p.dims()[0];
    let (sx, sy) = (2.0 * ndc.fx / ndc.width, 2.0 * ndc.fy / ndc.height);
    let zn = p.clone().slice([0..n, 2..3]).clamp(-1.0, 0.99);
    let z = (zn - 1.0).recip() * (2.0 * ndc.near) as f32;
    let x = p.clone().slice([0..n, 0..1]).neg() * z.clone() / sx as f32;
    let y = p.slice([0..n, 1..2]).neg() * z.clone() / sy as f32;
    Tensor::cat(vec![x, y, z], 1)
}

/// Where `[N, 3]` world points land in `camera`: `[N, 2]` continuous pixel coordinates
/// (centre of pixel (i, j) at (i + 0.5, j + 0.5)). Depths are clamped to stay positive.
pub fn project(points: Tensor<2>, camera: &Camera, device: &Device) -> Tensor<2> {
    let n = points.dims()[0];
    let r = camera.pose.rotation;
    let t = camera.pose.translation;
    // Camera coordinates: X_c = Rᵀ(X − t), i.e. the row vector (X − t)·R.
    let rot = Tensor::<2>::from_floats(
        [
            [r[0][0] as f32, r[0][1] as f32, r[0][2] as f32],
            [r[1][0] as f32, r[1][1] as f32, r[1][2] as f32],
            [r[2][0] as f32, r[2][1] as f32, r[2][2] as f32],
        ],
        device,
    );
    let centre =
        Tensor::<1>::from_floats([t[0] as f32, t[1] as f32, t[2] as f32], device).unsqueeze_dim::<2>(0);
    let pc = (points - centre).matmul(rot);
    let depth = pc.clone().slice([0..n, 2..3]).neg().clamp_min(1e-3);
    let k = &camera.intrinsics;
    let u = pc.clone().slice([0..n, 0..1]) / depth.clone() * k.fx as f32 + k.cx as f32;
    let v = pc.slice([0..n, 1..2]).neg() / depth * k.fy as f32 + k.cy as f32;
    Tensor::cat(vec![u, v], 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;
    use nerf_core::readback::host;
    use nerf_data::{Intrinsics, Pose};

    #[test]
    fn projection_matches_camera_project_and_ndc_inverts() {
        let dev = Device::flex();
        let cam = Camera::new(
            Intrinsics {
                fx: 100.0,
                fy: 90.0,
                cx: 64.0,
                cy: 48.5,
                width: 128,
                height: 96,
            },
            Pose::look_at([1.0, -3.0, 2.0], [0.0; 3], [0.0, 0.0, 1.0]),
        );
        let pts = [[0.1f32, 0.2, 0.3], [-0.5, 0.4, 0.0], [0.3, -0.2, -0.4]];
        let t = Tensor::<2>::from_data(TensorData::new(pts.concat(), [3, 2 + 1]), &dev);
        let uv = host(project(t, &cam, &dev));
        for (i, p) in pts.iter().enumerate() {
            let (u, v, _) = cam.project(p.map(f64::from)).unwrap();
            assert!((uv[2 * i] as f64 - u).abs() < 1e-3 && (uv[2 * i + 1] as f64 - v).abs() < 1e-3);
        }
        let ndc = Ndc {
            fx: 400.0,
            fy: 400.0,
            width: 504.0,
            height: 378.0,
            near: 1.0,
        };
        let world = [0.3, -0.2, -2.5];
        let q = ndc.from_world(world);
        let back = host(ndc_to_world(
            Tensor::<2>::from_data(TensorData::new(q.map(|v| v as f32).to_vec(), [1, 3]), &dev),
            &ndc,
        ));
        for a in 0..3 {
            assert!((back[a] as f64 - world[a]).abs() < 1e-4);
        }
    }
}
