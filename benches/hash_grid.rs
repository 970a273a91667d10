//! Hash-grid encoding throughput: the fused CPU op (forward + backward, sparse table gradient)
//! against the same encoding built from generic burn tensor ops (select + autodiff scatter-add).
//! Configuration from the foundation issue: 16 levels, 2 features, table 2^19, 2^18 random points.
//!
//! `cargo bench --bench hash_grid` prints samples/s for both and their ratio.

use std::time::{Duration, Instant};

use burn::tensor::{Device, Tensor, TensorData};
use criterion::{Criterion, criterion_group, criterion_main};
use nerf_core::encoding::hash_grid::{self, HashGrid, HashGridConfig};
use rand::{Rng, SeedableRng, rngs::StdRng};

const POINTS: usize = 1 << 18;

fn points(dev: &Device) -> Tensor<2> {
    let mut rng = StdRng::seed_from_u64(0);
    let data: Vec<f32> = (0..3 * POINTS).map(|_| rng.random_range(0.0..1.0)).collect();
    Tensor::from_data(TensorData::new(data, [POINTS, 3]), dev)
}

fn fused_step(grid: &std::sync::Arc<HashGrid>, x: Tensor<2>) {
    let feats = grid.encode(x);
    let _grads = feats.sum().backward();
    grid.zero_grad();
}

fn generic_step(cfg: &HashGridConfig, table: Tensor<2>, x: Tensor<2>) {
    let t = table.require_grad();
    let feats = hash_grid::encode_reference(cfg, t.clone(), x);
    let grads = feats.sum().backward();
    let _ = t.grad(&grads);
}

fn bench(c: &mut Criterion) {
    let dev = Device::flex().autodiff();
    let cfg = HashGridConfig::default();
    let grid = HashGrid::new(cfg.clone(), 0);
    let x = points(&dev);
    let table = hash_grid::table_tensor(&grid, &dev);

    let mut group = c.benchmark_group("hash_grid_fwd_bwd_2^18");
    group.sample_size(10).measurement_time(Duration::from_secs(8));
    group.bench_function("fused", |b| b.iter(|| fused_step(&grid, x.clone())));
    group.bench_function("generic_tensor_ops", |b| {
        b.iter(|| generic_step(&cfg, table.clone(), x.clone()))
    });
    group.finish();

    // A direct side-by-side measurement for the ratio (median of 5 after a warm-up).
    let time = |f: &dyn Fn()| {
        f();
        let mut v: Vec<f64> = (0..5)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64()
            })
            .collect();
        v.sort_by(f64::total_cmp);
        v[2]
    };
    let fused = time(&|| fused_step(&grid, x.clone()));
    let generic = time(&|| generic_step(&cfg, table.clone(), x.clone()));
    println!(
        "hash grid fwd+bwd, 2^18 points: fused {:.2} M samples/s ({:.1} ms), generic {:.2} M samples/s ({:.1} ms), fused/generic speed-up {:.1}x",
        POINTS as f64 / fused / 1e6,
        fused * 1e3,
        POINTS as f64 / generic / 1e6,
        generic * 1e3,
        generic / fused
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
