//! Fits a 2-D hash grid + tiny MLP to a 256×256 crop of a Blender lego view: the foundation's
//! check that the fused encoding, its backward pass and the sparse Adam update learn.
//!
//! `cargo run --release -p nerf-core --example fit_image [-- --steps 100 --image PATH]`
//! Prints PSNR against wall time and writes the fitted crop to `target/fit_image.png`.

use std::time::Instant;

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::activation::sigmoid;
use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::encoding::{HashGrid, HashGridConfig};
use nerf_core::metrics::psnr;
use nerf_core::mlp::MlpConfig;
use nerf_core::optim::AdamParams;
use nerf_data::Image;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let arg = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let steps: usize = arg("--steps").map_or(Ok(100), |s| s.parse())?;
    let path = match arg("--image") {
        Some(p) => std::path::PathBuf::from(p),
        None => nerf_data::shared_data()
            .ok_or("../shared/data not found; pass --image")?
            .join("nerf_synthetic/lego/train/r_1.png"),
    };
    // Crop the central 256x256 of the 800x800 view, composited on white.
    let (img, _) = Image::load(&path)?.composite_alpha([1.0; 3]);
    let (size, x0, y0) = (256usize, 272usize, 272usize);
    let mut target = Vec::with_capacity(size * size * 3);
    let mut coords = Vec::with_capacity(size * size * 2);
    for y in 0..size {
        for x in 0..size {
            target.extend_from_slice(img.pixel((y0 + y) * img.width as usize + x0 + x));
            coords.extend([(x as f32 + 0.5) / size as f32, (y as f32 + 0.5) / size as f32]);
        }
    }
    let device = Device::flex().autodiff();
    let n = size * size;
    let cfg = HashGridConfig {
        dims: 2,
        levels: 16,
        features: 2,
        log2_table: 15,
        base_resolution: 8,
        finest_resolution: 512,
        time_resolution: None,
        time_follows_space: false,
    };
    let grid = HashGrid::new(cfg.clone(), 0);
    let mut mlp = MlpConfig::new(cfg.output_dim(), 64, 2, 3).init(&device);
    let mut optim = AdamConfig::new().with_beta_2(0.99).with_epsilon(1e-15).init();
    let x = Tensor::<2>::from_data(TensorData::new(coords, [n, 2]), &device);
    let y = Tensor::<2>::from_data(TensorData::new(target.clone(), [n, 3]), &device);
    let start = Instant::now();
    let mut last = 0.0;
    for step in 1..=steps {
        let pred = sigmoid(mlp.forward(grid.encode(x.clone())));
        let loss = (pred - y.clone()).powi_scalar(2).mean();
        let grads = loss.backward();
        let lr = 1e-2;
        let grads = GradientsParams::from_grads(grads, &mlp);
        mlp = optim.step(lr, mlp, grads);
        grid.adam_step(&AdamParams::default(), lr);
        if step % 25 == 0 || step == steps {
            let pred = sigmoid(mlp.valid().forward(grid.encode(x.clone().inner())));
            let out = pred.into_data().try_into_vec_as::<f32>()?;
            last = psnr(&out, &target);
            println!(
                "step {step:4}  {:6.1} s  PSNR {last:.2} dB",
                start.elapsed().as_secs_f64()
            );
            if step == steps {
                let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target");
                Image::from_data(size as u32, size as u32, 3, out).save_png(&dir.join("fit_image.png"))?;
            }
        }
    }
    println!(
        "final PSNR {last:.2} dB after {steps} steps in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
