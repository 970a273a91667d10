//! NeRF's positional encoding γ(p) = [p, sin(2⁰p), cos(2⁰p), …, sin(2^{L−1}p), cos(2^{L−1}p)],
//! applied per component, without a π factor (as nerf-pytorch does). Built from burn ops, so
//! gradients flow to the input (NSFF needs them for warped sample positions).

use burn::config::Config;
use burn::module::Module;
use burn::tensor::Tensor;

#[derive(Config, Debug)]
pub struct PositionalEncodingConfig {
    /// Number of frequency bands L.
    pub bands: usize,
    /// Prepend the raw input.
    #[config(default = true)]
    pub include_input: bool,
}

impl PositionalEncodingConfig {
    pub fn init(&self) -> PositionalEncoding {
        PositionalEncoding {
            bands: self.bands,
            include_input: self.include_input,
        }
    }
}

#[derive(Module, Debug)]
pub struct PositionalEncoding {
    pub bands: usize,
    pub include_input: bool,
}

impl PositionalEncoding {
    /// Output width for an input of width `d`.
    pub fn output_dim(&self, d: usize) -> usize {
        d * (2 * self.bands + usize::from(self.include_input))
    }

    /// `[N, d]` → `[N, output_dim(d)]`, blocks ordered input, then (sin, cos) per band.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let mut blocks = Vec::with_capacity(2 * self.bands + 1);
        if self.include_input {
            blocks.push(x.clone());
        }
        for k in 0..self.bands {
            let scaled = x.clone() * (1u64 << k) as f32;
            blocks.push(scaled.clone().sin());
            blocks.push(scaled.cos());
        }
        Tensor::cat(blocks, 1)
    }
}
