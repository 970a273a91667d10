//! Numerical stress suite: extreme scene scales, degenerate rays, extreme densities through the
//! whole sampling → compositing path, and training at ten times the default learning rate.

use burn::tensor::{Device, Tensor, TensorData};
use nerf::config::{Preset, TrainConfig};
use nerf::trainer::Trainer;
use nerf_core::composite::composite;
use nerf_core::occupancy::{OccupancyConfig, OccupancyGrid};
use nerf_core::rays::Rays;
use nerf_core::sampler::{MarchConfig, Spacing, march, sample_pdf, stratified};
use rand::{Rng, SeedableRng, rngs::StdRng};

fn finite(v: &[f32]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Rays that stress the samplers: tiny and huge directions, axis-aligned and grazing rays,
/// origins on the box faces.
fn nasty_rays(scale: f32) -> Rays {
    let mut rays = Rays::default();
    let s = scale as f64;
    for (o, d) in [
        ([0.0, 0.0, 3.0 * s], [0.0, 0.0, -1.0]),
        ([0.0, 0.0, 3.0 * s], [1e-20, 1e-20, -1e-20]), // near-zero direction
        ([0.0, 0.0, 3.0 * s], [0.0, 0.0, -1e20]),      // huge direction
        ([s, s, 3.0 * s], [0.0, 0.0, -1.0]),           // grazing an edge of the box
        ([-3.0 * s, s, 0.0], [1.0, 0.0, 0.0]),         // along a face
        ([0.0, 0.0, 0.0], [0.3, -0.2, 0.9]),           // starting inside
        ([5.0 * s, 5.0 * s, 5.0 * s], [0.0, 0.0, -1.0]), // missing the box
    ] {
        rays.push(o, d);
    }
    rays
}

#[test]
fn tiny_and_huge_scenes_and_degenerate_rays_stay_finite() {
    let dev = Device::flex().autodiff();
    let mut rng = StdRng::seed_from_u64(0);
    for scale in [1e-3f32, 1.0, 1e3] {
        let aabb = [[-scale; 3], [scale; 3]];
        let rays = nasty_rays(scale);
        let mut grid = OccupancyGrid::new(
            OccupancyConfig {
                resolution: 16,
                ..Default::default()
            },
            aabb,
        );
        grid.update(0, scale * 0.01, &mut rng, &mut |p: &[f32]| {
            p.chunks(3)
                .map(|q| if q[0] > 0.0 { 1e3 / scale } else { 0.0 })
                .collect()
        });
        let cfg = MarchConfig {
            step: scale * 2.0 * 3f32.sqrt() / 256.0,
            cone_angle: 0.004,
            max_step: scale,
            max_samples: 512,
        };
        for g in [None, Some(&grid)] {
            let s = march(&rays, aabb, 0.0, 1e30, g, &cfg, Some(&mut rng));
            assert!(
                finite(&s.t) && finite(&s.t_start) && finite(&s.t_end),
                "scale {scale}: non-finite samples"
            );
            let layout = s.layout(&rays, false);
            assert!(finite(&layout.deltas));
            let n = s.num_samples();
            if n == 0 {
                continue;
            }
            // Densities from 0 to f32::MAX scaled by the scene size.
            let sigma: Vec<f32> = (0..n)
                .map(|i| [0.0, 1.0 / scale, 1e30, f32::MAX][i % 4])
                .collect();
            let ts = Tensor::<2>::from_data(TensorData::new(sigma, [n, 1]), &dev).require_grad();
            let tc =
                Tensor::<2>::from_data(TensorData::new(vec![0.5f32; 3 * n], [n, 3]), &dev).require_grad();
            let out = composite(ts.clone(), tc.clone(), None, &layout, 1e-4);
            let g2 = (out.clone() * out.clone()).sum().backward();
            let vals = out.inner().into_data().try_into_vec_as::<f32>().unwrap();
            assert!(finite(&vals), "scale {scale}: composite {vals:?}");
            for grad in [ts.grad(&g2).unwrap(), tc.grad(&g2).unwrap()] {
                assert!(
                    finite(&grad.into_data().try_into_vec_as::<f32>().unwrap()),
                    "scale {scale}: gradient"
                );
            }
            for r in 0..rays.len() {
                assert!(vals[4 * r + 3] <= 1.0 + 1e-5, "opacity above 1");
            }
        }
        // Stratified + hierarchical sampling on scaled bounds.
        let near = vec![0.5 * scale; rays.len()];
        let far = vec![4.0 * scale; rays.len()];
        for spacing in [Spacing::Depth, Spacing::Disparity] {
            let c = stratified(&near, &far, 32, spacing, Some(&mut rng));
            let w: Vec<f32> = (0..c.num_samples())
                .map(|_| rng.random::<f32>() * [0.0, 1e-30, 1.0, 1e30][rng.random_range(0..4)])
                .collect();
            let f = sample_pdf(&c, &w, 64, Some(&mut rng));
            assert!(
                finite(&f.t)
                    && f.t
                        .iter()
                        .all(|t| *t >= 0.5 * scale * 0.999 && *t <= 4.0 * scale * 1.001)
            );
        }
    }
}

#[test]
fn training_at_ten_times_the_learning_rate_never_goes_non_finite() {
    let dir = std::env::temp_dir().join(format!("nerf-stress-lr-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let data = dir.join("scene");
    let cfg = nerf_synth::SynthConfig::new(nerf_synth::Preset::Static)
        .with_size(24, 24)
        .with_views(16, 2);
    nerf_synth::generate(&cfg, &data).unwrap();
    for preset in [Preset::Fast, Preset::Vanilla] {
        let mut cfg = TrainConfig::new(preset, data.clone(), Default::default());
        cfg.lr *= 10.0;
        cfg.lr_final *= 10.0;
        cfg.steps = if preset == Preset::Fast { 150 } else { 12 };
        cfg.checkpoint_every = 5;
        cfg.vanilla.rays = 64;
        cfg.vanilla.width = 64;
        let dataset = nerf_data::load::load(&data, &cfg.load).unwrap();
        cfg.adapt_to(&dataset);
        let run = dir.join(format!("{preset:?}"));
        let mut t = Trainer::new(cfg, dataset, &run).unwrap();
        t.train(false).unwrap();
        // Non-finite steps are skipped, never applied: training reaches its step count, and the
        // final checkpoint loads and renders finite images.
        let resumed = Trainer::resume(&run, |_| Ok(())).unwrap();
        assert_eq!(resumed.step, resumed.cfg.steps, "{preset:?}");
        let e = nerf::eval::evaluate(
            &resumed.model,
            &resumed.dataset,
            &resumed.dataset.test,
            false,
            None,
            None,
            &resumed.device,
        )
        .unwrap();
        assert!(e.mean_psnr.is_finite(), "{preset:?}: {}", e.mean_psnr);
        eprintln!(
            "{preset:?} at 10x lr: {} steps, held-out PSNR {:.2}",
            resumed.step, e.mean_psnr
        );
    }
    std::fs::remove_dir_all(dir).unwrap();
}
