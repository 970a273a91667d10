//! Forward and forward+backward cost of the fields per 2^16 samples (static vanilla, static
//! fast, NSFF static + dynamic), and per-frame render time at 100×100 and 400×400 for the
//! static fast model and NSFF at a training time. Prints the dynamic/static ratios at the end.
//!
//! `cargo bench --bench fields`. The render scene is an occupancy grid holding a thin spherical
//! shell (what a trained object's grid looks like: a few cells thick around the surface), with
//! untrained fields, and NSFF renders at the training step (`render_step_scale` 1, not its
//! default of half), so the static and the dynamic renders march exactly the same samples.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};
use criterion::{Criterion, criterion_group};
use nerf::config::{Preset, TrainConfig};
use nerf::field::{FastField, VanillaField, VanillaFieldConfig};
use nerf::model::{StaticModel, fast_config};
use nerf::renderer::SceneBounds;
use nerf_core::field::{Field, FieldQuery};
use nerf_core::occupancy::OccupancyGrid;
use nerf_data::{Camera, Intrinsics, LoadOptions, Pose, rays::camera_rays};
use nsff::config::NsffConfig;
use nsff::model::{NsffFields, NsffModel, query_dynamic};
use nsff::render::{FlowMap, render_direct};
use rand::{Rng, SeedableRng, rngs::StdRng};

const SAMPLES: usize = 1 << 16;
const AABB: [[f32; 3]; 2] = [[-1.5; 3], [1.5; 3]];

/// Mean seconds per iteration of each benchmark, for the ratio table.
static TIMES: Mutex<BTreeMap<String, f64>> = Mutex::new(BTreeMap::new());

fn timed(name: &str, iters: u64, mut f: impl FnMut()) -> Duration {
    let start = Instant::now();
    for _ in 0..iters {
        f();
    }
    let elapsed = start.elapsed();
    TIMES
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .insert(name.to_string(), elapsed.as_secs_f64() / iters as f64);
    elapsed
}

fn inputs(dev: &Device) -> (Tensor<2>, Vec<f32>) {
    let mut rng = StdRng::seed_from_u64(0);
    let x: Vec<f32> = (0..3 * SAMPLES).map(|_| rng.random_range(-1.4..1.4)).collect();
    let dirs: Vec<f32> = (0..SAMPLES)
        .flat_map(|_| {
            let v = [0; 3].map(|_| rng.random_range(-1.0f32..1.0));
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-3);
            v.map(|c| c / n)
        })
        .collect();
    (Tensor::from_data(TensorData::new(x, [SAMPLES, 3]), dev), dirs)
}

fn configs() -> (TrainConfig, NsffConfig) {
    let path = std::path::PathBuf::from("bench");
    let base = TrainConfig::new(Preset::Fast, path.clone(), LoadOptions::default());
    let mut nsff = NsffConfig::new(Preset::Fast, path, LoadOptions::default());
    nsff.dynamic_grid.time_resolution = Some(23);
    // Same static field and marching for both, so the ratio isolates the dynamic branch (NSFF
    // renders march at half the training step by default, twice the static render's samples).
    nsff.base = base.clone();
    nsff.render_step_scale = 1.0;
    (base, nsff)
}

fn fast_forward(f: &FastField, x: &Tensor<2>, dirs: &[f32]) -> Tensor<1> {
    let out = f.query(FieldQuery::new(x.clone(), dirs));
    out.sigma.sum() + out.rgb.sum()
}

fn vanilla_forward(f: &VanillaField, x: &Tensor<2>, dirs: &[f32]) -> Tensor<1> {
    let out = f.query(FieldQuery::new(x.clone(), dirs));
    out.sigma.sum() + out.rgb.sum()
}

fn nsff_forward(f: &NsffFields, x: &Tensor<2>, dirs: &[f32]) -> Tensor<1> {
    let st = f.static_field.query(FieldQuery::new(x.clone(), dirs));
    let dynamic = f
        .dynamic
        .as_ref()
        .unwrap_or_else(|| unreachable!("built with a dynamic field"));
    let dy = query_dynamic(dynamic, x.clone(), 0.5, dirs);
    let mut total = st.sigma.sum() + st.rgb.sum() + dy.sigma.sum() + dy.rgb.sum();
    for (_, extra) in st.extras.0.into_iter().chain(dy.extras.0) {
        total = total + extra.sum();
    }
    total
}

fn field_benches(c: &mut Criterion) {
    let dev = Device::flex().autodiff();
    let (base, nsff_cfg) = configs();
    let vanilla = VanillaFieldConfig::new().init(&dev);
    let fast = fast_config(&base, AABB, 0).init(&dev, 0);
    let nsff = NsffFields::new(&nsff_cfg, AABB, true, &dev);
    let grids = nsff.host_params();
    let (x, dirs) = inputs(&dev);
    let xp = x.clone().inner();

    let mut g = c.benchmark_group("field_2^16_samples");
    g.sample_size(10).warm_up_time(Duration::from_millis(500));
    g.measurement_time(Duration::from_secs(3));
    let v_plain = vanilla.valid();
    let f_plain = fast.valid();
    let n_plain = nsff.valid();
    g.bench_function("vanilla/forward", |b| {
        b.iter_custom(|n| {
            timed("vanilla/forward", n, || {
                let _ = vanilla_forward(&v_plain, &xp, &dirs).into_scalar::<f32>();
            })
        })
    });
    g.bench_function("fast/forward", |b| {
        b.iter_custom(|n| {
            timed("fast/forward", n, || {
                let _ = fast_forward(&f_plain, &xp, &dirs).into_scalar::<f32>();
            })
        })
    });
    g.bench_function("nsff/forward", |b| {
        b.iter_custom(|n| {
            timed("nsff/forward", n, || {
                let _ = nsff_forward(&n_plain, &xp, &dirs).into_scalar::<f32>();
            })
        })
    });
    g.bench_function("vanilla/forward+backward", |b| {
        b.iter_custom(|n| {
            timed("vanilla/forward+backward", n, || {
                let _ = vanilla_forward(&vanilla, &x, &dirs).backward();
            })
        })
    });
    g.bench_function("fast/forward+backward", |b| {
        b.iter_custom(|n| {
            timed("fast/forward+backward", n, || {
                let _ = fast_forward(&fast, &x, &dirs).backward();
                fast.host_params().iter().for_each(|g| g.zero_grad());
            })
        })
    });
    g.bench_function("nsff/forward+backward", |b| {
        b.iter_custom(|n| {
            timed("nsff/forward+backward", n, || {
                let _ = nsff_forward(&nsff, &x, &dirs).backward();
                grids.iter().for_each(|g| g.zero_grad());
            })
        })
    });
    g.finish();
}

/// A grid occupied on a spherical shell of radius 0.8 about two cells thick.
fn shell_grid(cfg: &TrainConfig) -> OccupancyGrid {
    let mut grid = OccupancyGrid::new(cfg.fast.occupancy.clone(), AABB);
    let cell = grid.cell_size()[0];
    let values = (0..grid.num_cells())
        .map(|i| {
            let p = grid.cell_center(i);
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            if (r - 0.8).abs() < cell { 1.0 } else { 0.0 }
        })
        .collect();
    grid.set_values(values);
    grid
}

fn render_benches(c: &mut Criterion) {
    let dev = Device::flex().autodiff();
    let (base, nsff_cfg) = configs();
    let bounds = SceneBounds::object(2.0, 6.0, AABB);
    let mut model = StaticModel::new(&base, bounds.clone(), &dev);
    model.occupancy = Some(shell_grid(&base));
    let mut nsff = NsffModel::new(&nsff_cfg, bounds, vec![0.0, 0.5, 1.0], true, &dev);
    if let Some(o) = nsff.occupancy.as_mut() {
        o.with_bins_mut(|bins| bins.iter_mut().for_each(|g| *g = shell_grid(&base)));
    }
    let mut g = c.benchmark_group("render_frame");
    g.sample_size(10).warm_up_time(Duration::from_millis(500));
    g.measurement_time(Duration::from_secs(5));
    for size in [100u32, 400] {
        let pose = Pose::look_at([0.0, -4.0, 1.0], [0.0; 3], [0.0, 0.0, 1.0]);
        let camera = Camera::new(Intrinsics::from_fov_x(0.69, size, size), pose);
        let rays = camera_rays(&camera);
        let id = format!("static/{size}x{size}");
        g.bench_function(&id, |b| {
            b.iter_custom(|n| {
                timed(&id, n, || {
                    let _ = model.render_rays(&rays, Some([1.0; 3]), &dev);
                })
            })
        });
        let id = format!("nsff/{size}x{size}");
        g.bench_function(&id, |b| {
            b.iter_custom(|n| {
                timed(&id, n, || {
                    for start in (0..rays.len()).step_by(16384) {
                        let part = rays.slice(start..(start + 16384).min(rays.len()));
                        let _ = render_direct(&nsff, &part, 0.5, Some([1.0; 3]), FlowMap::Skip, &dev);
                    }
                })
            })
        });
    }
    g.finish();
}

fn print_ratios() {
    let t = TIMES.lock().unwrap_or_else(|e| e.into_inner());
    let get = |k: &str| t.get(k).copied().unwrap_or(f64::NAN);
    println!(
        "\n{:<34} {:>12} {:>12} {:>8}",
        "", "static ms", "nsff ms", "ratio"
    );
    for pass in ["forward", "forward+backward"] {
        let (a, b) = (get(&format!("fast/{pass}")), get(&format!("nsff/{pass}")));
        println!(
            "{:<34} {:>12.1} {:>12.1} {:>7.2}x",
            format!("2^16 samples, fast, {pass}"),
            1e3 * a,
            1e3 * b,
            b / a
        );
        println!(
            "{:<34} {:>12.1} {:>12} {:>8}",
            format!("2^16 samples, vanilla, {pass}"),
            1e3 * get(&format!("vanilla/{pass}")),
            "-",
            "-"
        );
    }
    for size in [100, 400] {
        let (a, b) = (
            get(&format!("static/{size}x{size}")),
            get(&format!("nsff/{size}x{size}")),
        );
        println!(
            "{:<34} {:>12.1} {:>12.1} {:>7.2}x",
            format!("render {size}x{size} (per frame)"),
            1e3 * a,
            1e3 * b,
            b / a
        );
    }
    println!("dynamic/static ratio = NSFF (static + dynamic field) over the static fast field");
}

criterion_group!(benches, field_benches, render_benches);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    print_ratios();
}
