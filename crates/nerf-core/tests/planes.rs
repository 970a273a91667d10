//! The space-time planes encoding against an f64 implementation written from its definition
//! (a 3-D grid times three (axis, t) planes, each a multiresolution grid), and finite differences.

use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::encoding::SpaceTimePlanes;
use nerf_core::encoding::hash_grid::{HashGridConfig, levels};

mod support;
use rand::{Rng, SeedableRng, rngs::StdRng};
use support::encode_f64_nd;

/// Fine space levels hashed, planes dense, time capped at 5 cells.
fn config() -> HashGridConfig {
    HashGridConfig {
        dims: 4,
        levels: 4,
        features: 2,
        log2_table: 8,
        base_resolution: 4,
        finest_resolution: 32,
        time_resolution: Some(5),
        time_follows_space: false,
    }
}

/// f64 planes encoding of (x, y, z, t) from the four tables (space, then the x, y, z planes).
fn planes_f64(cfg: &HashGridConfig, tables: &[Vec<f32>], p: [f64; 4]) -> Vec<f64> {
    let (space, plane) = SpaceTimePlanes::configs(cfg);
    let mut out = encode_f64_nd(&space, &tables[0], &p[..3]);
    for a in 0..3 {
        let e = encode_f64_nd(&plane, &tables[1 + a], &[p[a], p[3]]);
        out.iter_mut().zip(e).for_each(|(o, v)| *o *= v);
    }
    out
}

fn host(t: Tensor<2>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().unwrap()
}

/// Planes with non-trivial tables (a fresh encoding's planes are all ones).
fn filled(cfg: &HashGridConfig) -> (SpaceTimePlanes, Vec<Vec<f32>>) {
    let enc = SpaceTimePlanes::new(cfg, 1);
    let mut rng = StdRng::seed_from_u64(2);
    let mut tables = Vec::new();
    for g in enc.grids() {
        let t: Vec<f32> = (0..g.num_params()).map(|_| rng.random_range(-1.0..1.0)).collect();
        g.set_table(t.clone()).unwrap();
        tables.push(t);
    }
    (enc, tables)
}

#[test]
fn planes_start_at_one_so_the_encoding_starts_as_the_space_grid() {
    let cfg = config();
    let enc = SpaceTimePlanes::new(&cfg, 7);
    assert!(enc.planes.iter().all(|p| p.table().iter().all(|&v| v == 1.0)));
    let pts = [0.3f32, 0.6, 0.9, 0.1, 0.5, 0.2, 0.4, 0.8];
    let dev = Device::flex();
    let got = host(enc.encode(Tensor::from_data(TensorData::new(pts.to_vec(), [2, 4]), &dev)));
    let space = enc.space.encode_host(&[0.3, 0.6, 0.9, 0.5, 0.2, 0.4]);
    assert_eq!(got, space);
}

#[test]
fn forward_and_gradients_match_the_f64_definition() {
    let cfg = config();
    let (enc, tables) = filled(&cfg);
    let dev = Device::flex().autodiff();
    let n = 40;
    let mut rng = StdRng::seed_from_u64(3);
    let pts: Vec<f32> = (0..4 * n).map(|_| rng.random_range(0.02..0.98)).collect();
    let width = cfg.output_dim();
    let upstream: Vec<f32> = (0..n * width).map(|_| rng.random_range(-1.0..1.0)).collect();
    let x = Tensor::<2>::from_data(TensorData::new(pts.clone(), [n, 4]), &dev).require_grad();
    let out = enc.encode(x.clone());
    let fwd = host(out.clone().inner());
    let up = Tensor::<2>::from_data(TensorData::new(upstream.clone(), [n, width]), &dev);
    let g = (out * up).sum().backward();
    let dx = host(x.grad(&g).unwrap());

    let point = |p: &[f32], k: usize| [0, 1, 2, 3].map(|a| p[4 * k + a] as f64);
    let loss = |tabs: &[Vec<f32>], p: &[f32]| -> f64 {
        (0..n)
            .map(|k| {
                let e = planes_f64(&cfg, tabs, point(p, k));
                e.iter()
                    .zip(&upstream[k * width..])
                    .map(|(a, b)| a * *b as f64)
                    .sum::<f64>()
            })
            .sum()
    };
    for k in 0..n {
        let want = planes_f64(&cfg, &tables, point(&pts, k));
        for j in 0..width {
            let got = fwd[k * width + j] as f64;
            assert!(
                (got - want[j]).abs() < 1e-4,
                "point {k} feature {j}: {got} vs {}",
                want[j]
            );
        }
    }
    // Tables: the loss is linear in each table on its own, so a central difference is exact.
    for (gi, grid) in enc.grids().iter().enumerate() {
        let grad = grid.grad();
        assert!(grid.touched() > 0, "grid {gi} got no gradient");
        for i in (0..grad.len()).step_by(11) {
            let (mut a, mut b) = (tables.to_vec(), tables.to_vec());
            a[gi][i] += 0.5;
            b[gi][i] -= 0.5;
            let fd = loss(&a, &pts) - loss(&b, &pts);
            assert!(
                (grad[i] as f64 - fd).abs() < 1e-3 * (1.0 + fd.abs()),
                "grid {gi} entry {i}: {} vs {fd}",
                grad[i]
            );
        }
    }
    // Points, time included, away from the finest cells' faces.
    let finest = levels(&cfg).last().unwrap().resolutions;
    let h = 1e-5f32;
    for i in 0..4 * n {
        let frac = (pts[i] * finest[i % 4] as f32).fract();
        if !(0.01..0.99).contains(&frac) {
            continue;
        }
        let (mut a, mut b) = (pts.clone(), pts.clone());
        a[i] += h;
        b[i] -= h;
        let fd = (loss(&tables, &a) - loss(&tables, &b)) / (a[i] as f64 - b[i] as f64);
        let err = (dx[i] as f64 - fd).abs() / fd.abs().max(1.0);
        assert!(err < 2e-3, "coordinate {i}: {} vs {fd}", dx[i]);
    }
}
