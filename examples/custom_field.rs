//! A new field in one file, trained by the shared pipeline.
//!
//! `SmallMlpField` is a plain NeRF-style MLP: positions, scaled into [−1, 1] over the scene box,
//! go through a positional encoding (6 bands) and three ReLU layers of width 64 to a density and a
//! view-independent colour. Implementing `nerf_core::field::Field` (density at points; density,
//! colour and extras for a query) is all it takes: `nerf::trainer::Trainer::with_field` trains it
//! with the static pipeline's occupancy marching, the shared render function, optimiser step,
//! checkpoints and training loop, and `nerf::eval::evaluate` scores it.
//!
//! ```sh
//! cargo run --release --example custom_field -- [DATA] [--time-budget SECS] [--out RUN_DIR]
//! ```
//! DATA defaults to the tiny lego scene in `../shared/data`. The README records what it reaches.

use std::path::PathBuf;

use burn::module::Module;
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Tensor};
use nerf::config::{Preset, TrainConfig};
use nerf::renderer::SceneBounds;
use nerf::trainer::{Trainer, load_dataset};
use nerf_core::encoding::{PositionalEncoding, PositionalEncodingConfig};
use nerf_core::field::{Density, Extras, Field, FieldOutputs, FieldQuery};

/// Density and colour from one small MLP over positionally encoded points.
#[derive(Module, Debug)]
pub struct SmallMlpField {
    layers: Vec<Linear>,
    /// Hidden features → (raw density, 3 raw colour channels).
    head: Linear,
    encoding: PositionalEncoding,
    /// Scene-box centre and half-size: positions are mapped to [−1, 1]^3 before encoding.
    #[module(skip)]
    centre: [f32; 3],
    #[module(skip)]
    half: [f32; 3],
}

impl SmallMlpField {
    pub fn new(aabb: [[f32; 3]; 2], device: &Device) -> Self {
        let encoding = PositionalEncodingConfig::new(6).init();
        let width = 64;
        let mut input = encoding.output_dim(3);
        let layers = (0..3)
            .map(|_| {
                let layer = LinearConfig::new(input, width).init(device);
                input = width;
                layer
            })
            .collect();
        SmallMlpField {
            layers,
            head: LinearConfig::new(width, 4).init(device),
            encoding,
            centre: std::array::from_fn(|a| 0.5 * (aabb[0][a] + aabb[1][a])),
            half: std::array::from_fn(|a| 0.5 * (aabb[1][a] - aabb[0][a])),
        }
    }

    /// `[S, 4]`: raw density and raw colour.
    fn raw(&self, positions: Tensor<2>) -> Tensor<2> {
        let device = positions.device();
        let centre = Tensor::<1>::from_floats(self.centre, &device).unsqueeze_dim::<2>(0);
        let scale = Tensor::<1>::from_floats(self.half.map(|h| 1.0 / h), &device).unsqueeze_dim::<2>(0);
        let mut h = self.encoding.forward((positions - centre) * scale);
        for layer in &self.layers {
            h = relu(layer.forward(h));
        }
        self.head.forward(h)
    }

    /// σ = exp(raw), clamped so one bad step cannot overflow (Instant-NGP's activation).
    fn sigma(raw: &Tensor<2>) -> Tensor<2> {
        let n = raw.dims()[0];
        raw.clone().slice([0..n, 0..1]).clamp_max(11.0).exp()
    }
}

impl Field for SmallMlpField {
    fn density(&self, positions: Tensor<2>, _time: Option<Tensor<2>>) -> Density {
        Density {
            sigma: Self::sigma(&self.raw(positions)),
            extras: Extras::default(),
        }
    }

    fn query(&self, query: FieldQuery<'_>) -> FieldOutputs {
        let raw = self.raw(query.positions);
        let n = raw.dims()[0];
        FieldOutputs {
            sigma: Self::sigma(&raw),
            rgb: sigmoid(raw.slice([0..n, 1..4])),
            extras: Extras::default(),
        }
    }
}

/// How the trainer builds the field (and rebuilds it when resuming or rolling back).
fn build(_cfg: &TrainConfig, bounds: &SceneBounds, device: &Device) -> SmallMlpField {
    SmallMlpField::new(bounds.aabb, device)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let (mut data, mut budget, mut out) = (None, 60.0, PathBuf::from("runs/custom_field"));
    while let Some(a) = args.next() {
        match a.as_str() {
            "--time-budget" => budget = args.next().ok_or("--time-budget needs SECS")?.parse()?,
            "--out" => out = args.next().ok_or("--out needs a folder")?.into(),
            _ => data = Some(PathBuf::from(a)),
        }
    }
    let data = match data {
        Some(d) => d,
        None => nerf_data::shared_data()
            .ok_or("no DATA given and ../shared/data not found")?
            .join("lego_tiny/tiny_nerf_data.npz"),
    };
    // The fast preset's sampling (occupancy marching, adaptive ray count) and schedule; the
    // learning rate suits a plain MLP better than a hash grid's 1e-2.
    let mut cfg = TrainConfig::new(Preset::Fast, data, Default::default());
    let dataset = load_dataset(&cfg)?;
    cfg.adapt_to(&dataset);
    cfg.time_budget = Some(budget);
    cfg.steps = usize::MAX;
    cfg.lr = 5e-3;
    cfg.lr_final = 5e-4;
    let mut trainer = Trainer::with_field(cfg, dataset, &out, build)?;
    trainer.train(true)?;
    let result = nerf::eval::evaluate(
        &trainer.model,
        &trainer.dataset,
        &trainer.dataset.test,
        true,
        None,
        None,
        &trainer.device,
    )?;
    println!(
        "{} steps in {:.0} s; {} test views, mean_ssim {:.4}",
        trainer.step,
        trainer.elapsed,
        result.views.len(),
        result.mean_ssim.unwrap_or(f64::NAN)
    );
    println!("mean_psnr {:.4}", result.mean_psnr);
    Ok(())
}
