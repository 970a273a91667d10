//! A plain multilayer perceptron: the tiny networks of the fast field and NSFF's heads.

use burn::config::Config;
use burn::module::Module;
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

#[derive(Config, Debug)]
pub struct MlpConfig {
    pub input: usize,
    pub hidden: usize,
    /// Number of hidden layers (each followed by ReLU).
    pub hidden_layers: usize,
    pub output: usize,
}

impl MlpConfig {
    pub fn init(&self, device: &Device) -> Mlp {
        let mut layers = Vec::with_capacity(self.hidden_layers + 1);
        let mut width = self.input;
        for _ in 0..self.hidden_layers {
            layers.push(LinearConfig::new(width, self.hidden).init(device));
            width = self.hidden;
        }
        layers.push(LinearConfig::new(width, self.output).init(device));
        Mlp { layers }
    }
}

/// Linear layers with ReLU between them and no activation on the output.
#[derive(Module, Debug)]
pub struct Mlp {
    pub layers: Vec<Linear>,
}

impl Mlp {
    /// `[N, input]` → `[N, output]`.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let last = self.layers.len() - 1;
        self.layers.iter().enumerate().fold(x, |h, (i, layer)| {
            let h = layer.forward(h);
            if i < last { relu(h) } else { h }
        })
    }
}
