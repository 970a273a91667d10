//! Real spherical harmonics of unit view directions (degree ≤ 4, so up to 16 coefficients), the
//! Instant-NGP direction encoding. View directions never need gradients, so this is computed on
//! the host and uploaded as a constant tensor.

use burn::config::Config;
use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};

#[derive(Config, Debug)]
pub struct SphericalHarmonicsConfig {
    /// Number of bands (degree + 1), 1 to 4: output width `degree²`.
    #[config(default = 4)]
    pub degree: usize,
}

impl SphericalHarmonicsConfig {
    pub fn init(&self) -> SphericalHarmonics {
        assert!((1..=4).contains(&self.degree), "SH degree must be 1 to 4");
        SphericalHarmonics { degree: self.degree }
    }
}

#[derive(Module, Debug)]
pub struct SphericalHarmonics {
    pub degree: usize,
}

impl SphericalHarmonics {
    pub fn output_dim(&self) -> usize {
        self.degree * self.degree
    }

    /// `[N, 3]` unit directions (host) → `[N, degree²]` on `device`.
    pub fn forward(&self, dirs: &[f32], device: &Device) -> Tensor<2> {
        let n = dirs.len() / 3;
        let out = encode(dirs, self.degree);
        Tensor::from_data(TensorData::new(out, [n, self.output_dim()]), device)
    }
}

/// Host SH basis, orthonormal over the unit sphere.
pub fn encode(dirs: &[f32], degree: usize) -> Vec<f32> {
    let width = degree * degree;
    let mut out = Vec::with_capacity(dirs.len() / 3 * width);
    for d in dirs.chunks_exact(3) {
        let (x, y, z) = (d[0], d[1], d[2]);
        let (xx, yy, zz) = (x * x, y * y, z * z);
        let all = [
            0.282_094_8,
            -0.488_602_5 * y,
            0.488_602_5 * z,
            -0.488_602_5 * x,
            1.092_548_4 * x * y,
            -1.092_548_4 * y * z,
            0.946_174_7 * zz - 0.315_391_57,
            -1.092_548_4 * x * z,
            0.546_274_2 * (xx - yy),
            0.590_043_6 * y * (yy - 3.0 * xx),
            2.890_611_4 * x * y * z,
            0.457_045_8 * y * (1.0 - 5.0 * zz),
            0.373_176_33 * z * (5.0 * zz - 3.0),
            0.457_045_8 * x * (1.0 - 5.0 * zz),
            1.445_305_7 * z * (xx - yy),
            0.590_043_6 * x * (3.0 * yy - xx),
        ];
        out.extend_from_slice(&all[..width]);
    }
    out
}

#[cfg(test)]
mod tests {
    /// Monte Carlo check that the basis is orthonormal on the sphere: ∫ Y_i Y_j dΩ = δ_ij.
    #[test]
    fn basis_is_orthonormal() {
        let n = 200_000;
        let mut dirs = Vec::with_capacity(3 * n);
        // Fibonacci sphere: near-uniform deterministic directions.
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            dirs.extend([(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]);
        }
        let y = super::encode(&dirs, 4);
        for i in 0..16 {
            for j in 0..16 {
                let mut s = 0.0f64;
                for k in 0..n {
                    s += y[k * 16 + i] as f64 * y[k * 16 + j] as f64;
                }
                let integral = s * 4.0 * std::f64::consts::PI / n as f64;
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((integral - want).abs() < 2e-3, "<Y{i}, Y{j}> = {integral}");
            }
        }
    }
}
