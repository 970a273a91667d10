//! The NeRF paper's field: positional encoding (10 bands for position, 4 for direction), an
//! 8×256 ReLU trunk with the encoded input concatenated again after layer 4, a density head, and
//! a view-dependent colour head (256 features + γ(d) → 128 → 3).

use burn::config::Config;
use burn::module::Module;
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::encoding::{PositionalEncoding, PositionalEncodingConfig};
use nerf_core::field::{Density, Extras, Field, FieldOutputs, FieldQuery};

#[derive(Config, Debug)]
pub struct VanillaFieldConfig {
    /// Input dimension: 3 (x, y, z) or 4 (x, y, z, t for NSFF's dynamic field).
    #[config(default = 3)]
    pub input_dims: usize,
    #[config(default = 8)]
    pub depth: usize,
    #[config(default = 256)]
    pub width: usize,
    /// The encoded input is concatenated to the activation after this layer.
    #[config(default = 4)]
    pub skip: usize,
    #[config(default = 10)]
    pub position_bands: usize,
    #[config(default = 4)]
    pub direction_bands: usize,
    /// Extra raw outputs from a linear head on the trunk (view independent).
    #[config(default = 0)]
    pub extra_outputs: usize,
}

impl VanillaFieldConfig {
    pub fn init(&self, device: &Device) -> VanillaField {
        let pe_x = PositionalEncodingConfig::new(self.position_bands).init();
        let pe_d = PositionalEncodingConfig::new(self.direction_bands).init();
        let x_dim = pe_x.output_dim(self.input_dims);
        let d_dim = pe_d.output_dim(3);
        let trunk = (0..self.depth)
            .map(|i| {
                let input = if i == 0 {
                    x_dim
                } else if i == self.skip + 1 {
                    self.width + x_dim
                } else {
                    self.width
                };
                LinearConfig::new(input, self.width).init(device)
            })
            .collect();
        VanillaField {
            trunk,
            sigma: LinearConfig::new(self.width, 1).init(device),
            feature: LinearConfig::new(self.width, self.width).init(device),
            view: LinearConfig::new(self.width + d_dim, self.width / 2).init(device),
            rgb: LinearConfig::new(self.width / 2, 3).init(device),
            extra: (self.extra_outputs > 0)
                .then(|| LinearConfig::new(self.width, self.extra_outputs).init(device)),
            pe_x,
            pe_d,
            skip: self.skip,
        }
    }
}

#[derive(Module, Debug)]
pub struct VanillaField {
    pub trunk: Vec<Linear>,
    pub sigma: Linear,
    pub feature: Linear,
    pub view: Linear,
    pub rgb: Linear,
    pub extra: Option<Linear>,
    pub pe_x: PositionalEncoding,
    pub pe_d: PositionalEncoding,
    pub skip: usize,
}

impl VanillaField {
    /// The trunk's features `[S, W]`. A time input (NSFF's dynamic field) is encoded jointly with
    /// the position, mapped from [0, 1] to [−1, 1] as NSFF does.
    fn trunk(&self, positions: Tensor<2>, time: Option<Tensor<2>>) -> Tensor<2> {
        let input = match time {
            Some(t) => Tensor::cat(vec![positions, t * 2.0 - 1.0], 1),
            None => positions,
        };
        let x = self.pe_x.forward(input);
        let mut h = x.clone();
        for (i, layer) in self.trunk.iter().enumerate() {
            if i == self.skip + 1 {
                h = Tensor::cat(vec![x.clone(), h], 1);
            }
            h = relu(layer.forward(h));
        }
        h
    }

    fn extras(&self, features: Tensor<2>) -> Extras {
        super::raw_extras(self.extra.as_ref(), features)
    }
}

impl Field for VanillaField {
    /// σ = ReLU(raw).
    fn density(&self, positions: Tensor<2>, time: Option<Tensor<2>>) -> Density {
        let h = self.trunk(positions, time);
        Density {
            sigma: relu(self.sigma.forward(h.clone())),
            extras: self.extras(h),
        }
    }

    /// σ = ReLU(raw + noise), nerf-pytorch's activation (noise only while training).
    fn query(&self, query: FieldQuery<'_>) -> FieldOutputs {
        let device = query.positions.device();
        let n = query.positions.dims()[0];
        let h = self.trunk(query.positions, query.time);
        let raw = self.sigma.forward(h.clone());
        let raw = match query.density_noise {
            Some(noise) => raw + noise,
            None => raw,
        };
        let d = Tensor::<2>::from_data(TensorData::new(query.dirs.to_vec(), [n, 3]), &device);
        let feat = self.feature.forward(h.clone());
        let v = relu(
            self.view
                .forward(Tensor::cat(vec![feat, self.pe_d.forward(d)], 1)),
        );
        FieldOutputs {
            sigma: relu(raw),
            rgb: sigmoid(self.rgb.forward(v)),
            extras: self.extras(h),
        }
    }
}
