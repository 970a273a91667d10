//! The fused hash-grid op against an independent f64 implementation written from the paper's
//! formulas, the generic burn tensor-op version, and finite differences.

use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::encoding::hash_grid::{self, HashGrid, HashGridConfig, Level, levels};
use nerf_core::optim::AdamParams;
use rand::{Rng, SeedableRng, rngs::StdRng};

mod support;
use support::encode_f64_nd;

fn small() -> HashGridConfig {
    // Coarse levels dense, fine levels hashed into 2^10 entries.
    HashGridConfig {
        dims: 3,
        levels: 6,
        features: 2,
        log2_table: 10,
        base_resolution: 4,
        finest_resolution: 64,
        time_resolution: None,
        time_follows_space: false,
    }
}

fn host(t: Tensor<2>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().unwrap()
}

/// f64 encoding from the definition: corners, exact primes in u32 wrapping arithmetic, weights.
fn encode_f64(cfg: &HashGridConfig, table: &[f32], x: [f64; 3]) -> Vec<f64> {
    let mut out = Vec::new();
    let primes: [u64; 3] = [1, 2_654_435_761, 805_459_861];
    for level in levels(cfg) {
        let res = level.resolution as f64;
        let mut feats = vec![0.0; cfg.features];
        let p = x.map(|v| v.clamp(0.0, 1.0) * res);
        let base = p.map(|v| v.floor().min(res - 1.0));
        for corner in 0..8 {
            let mut w = 1.0;
            let mut v = [0u64; 3];
            for a in 0..3 {
                let up = (corner >> a) & 1;
                v[a] = base[a] as u64 + up as u64;
                let f = p[a] - base[a];
                w *= if up == 1 { f } else { 1.0 - f };
            }
            let idx = if level.dense {
                let s = level.resolution as u64 + 1;
                v[0] + v[1] * s + v[2] * s * s
            } else {
                let h = (v[0] * primes[0]) as u32 ^ (v[1] * primes[1]) as u32 ^ (v[2] * primes[2]) as u32;
                (h as u64) % level.size as u64
            };
            let row = level.offset + idx as usize;
            for f in 0..cfg.features {
                feats[f] += w * table[row * cfg.features + f] as f64;
            }
        }
        out.extend(feats);
    }
    out
}

fn random_points(n: usize, seed: u64) -> Vec<f32> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..3 * n).map(|_| rng.random_range(0.0..1.0)).collect()
}

#[test]
fn level_layout_follows_the_paper() {
    let cfg = HashGridConfig::default();
    let lv = levels(&cfg);
    assert_eq!(lv[0].resolution, 16);
    assert!(
        (cfg.growth().exp() - 1.3819).abs() < 1e-3,
        "growth factor {}",
        cfg.growth().exp()
    );
    assert!(
        (2040..=2048).contains(&lv[15].resolution),
        "finest {}",
        lv[15].resolution
    );
    for l in &lv {
        assert!(l.size <= 1 << 19);
        assert_eq!(l.dense, (l.resolution as usize + 1).pow(3) <= 1 << 19);
    }
    // Dense levels index bijectively.
    let l = Level {
        resolution: 5,
        resolutions: [5; 4],
        offset: 0,
        size: 216,
        dense: true,
    };
    let mut seen = vec![false; 216];
    for z in 0..6 {
        for y in 0..6 {
            for x in 0..6 {
                let i = hash_grid::corner_index(&l, &[x, y, z]);
                assert!(!seen[i]);
                seen[i] = true;
            }
        }
    }
    // Hashed indices stay in the table.
    let h = Level {
        resolution: 1000,
        resolutions: [1000; 4],
        offset: 0,
        size: 1 << 10,
        dense: false,
    };
    for v in [[0u32, 0, 0], [999, 1, 7], [1000, 1000, 1000]] {
        assert!(hash_grid::corner_index(&h, &v) < 1 << 10);
    }
}

#[test]
fn forward_matches_f64_definition_and_generic_tensor_ops() {
    let cfg = small();
    let grid = HashGrid::new(cfg.clone(), 1);
    // Non-trivial table values so errors show.
    let table: Vec<f32> = (0..grid.num_params())
        .map(|i| ((i * 7919) % 1000) as f32 / 500.0 - 1.0)
        .collect();
    let grid = HashGrid::with_table(cfg.clone(), table.clone());
    let n = 500;
    let mut pts = random_points(n, 2);
    pts[0..3].copy_from_slice(&[0.0, 1.0, 0.5]); // faces of the unit cube
    pts[3..6].copy_from_slice(&[1.2, -0.1, 1.0]); // outside: clamped
    let fused = grid.encode_host(&pts);
    let dev = Device::flex();
    let generic = host(hash_grid::encode_reference(
        &cfg,
        Tensor::from_data(TensorData::new(table.clone(), [grid.num_entries(), 2]), &dev),
        Tensor::from_data(TensorData::new(pts.clone(), [n, 3]), &dev),
    ));
    let width = cfg.output_dim();
    for p in 0..n {
        let want = encode_f64(
            &cfg,
            &table,
            [pts[3 * p] as f64, pts[3 * p + 1] as f64, pts[3 * p + 2] as f64],
        );
        for j in 0..width {
            assert!(
                (fused[p * width + j] as f64 - want[j]).abs() < 1e-4,
                "point {p} feature {j}"
            );
            assert!(
                (generic[p * width + j] as f64 - want[j]).abs() < 1e-4,
                "generic, point {p} feature {j}"
            );
        }
    }
}

#[test]
fn gradients_match_generic_autodiff_and_finite_differences() {
    let cfg = small();
    let dev = Device::flex().autodiff();
    let grid = HashGrid::new(cfg.clone(), 3);
    let table: Vec<f32> = (0..grid.num_params())
        .map(|i| ((i * 104_729) % 997) as f32 / 500.0 - 1.0)
        .collect();
    let grid = HashGrid::with_table(cfg.clone(), table.clone());
    let n = 64;
    let pts = random_points(n, 4);
    let width = cfg.output_dim();
    let mut rng = StdRng::seed_from_u64(5);
    let upstream: Vec<f32> = (0..n * width).map(|_| rng.random_range(-1.0..1.0)).collect();
    let up = Tensor::<2>::from_data(TensorData::new(upstream.clone(), [n, width]), &dev);

    // Fused: table gradient in the grid's buffer, position gradient through the graph.
    let x = Tensor::<2>::from_data(TensorData::new(pts.clone(), [n, 3]), &dev).require_grad();
    let g = (grid.encode(x.clone()) * up.clone()).sum().backward();
    let dx_fused = host(x.grad(&g).unwrap());
    let dtable_fused = grid.grad();
    assert!(grid.touched() > 0);

    // Generic: burn autodiff through select/scatter.
    let t =
        Tensor::<2>::from_data(TensorData::new(table.clone(), [grid.num_entries(), 2]), &dev).require_grad();
    let x2 = Tensor::<2>::from_data(TensorData::new(pts.clone(), [n, 3]), &dev).require_grad();
    let g2 = (hash_grid::encode_reference(&cfg, t.clone(), x2.clone()) * up)
        .sum()
        .backward();
    let dtable_generic = host(t.grad(&g2).unwrap());
    let dx_generic = host(x2.grad(&g2).unwrap());
    for (i, (a, b)) in dtable_fused.iter().zip(&dtable_generic).enumerate() {
        assert!((a - b).abs() < 1e-4, "table grad {i}: {a} vs {b}");
    }
    for (i, (a, b)) in dx_fused.iter().zip(&dx_generic).enumerate() {
        assert!(
            (a - b).abs() < 1e-2 * (1.0 + b.abs()),
            "position grad {i}: {a} vs {b}"
        );
    }

    // Finite differences of the f64 definition (linear in the table; piecewise linear in x, so
    // use a step well inside the finest cell).
    let loss = |tab: &[f32], p: &[f32]| -> f64 {
        (0..n)
            .map(|k| {
                let e = encode_f64(
                    &cfg,
                    tab,
                    [p[3 * k] as f64, p[3 * k + 1] as f64, p[3 * k + 2] as f64],
                );
                e.iter()
                    .zip(&upstream[k * width..])
                    .map(|(a, b)| a * *b as f64)
                    .sum::<f64>()
            })
            .sum()
    };
    for i in (0..table.len()).step_by(37) {
        let (mut a, mut b) = (table.clone(), table.clone());
        a[i] += 0.5;
        b[i] -= 0.5;
        let fd = (loss(&a, &pts) - loss(&b, &pts)) / 1.0;
        assert!(
            (dtable_fused[i] as f64 - fd).abs() < 1e-3 * (1.0 + fd.abs()),
            "table {i}: {} vs {fd}",
            dtable_fused[i]
        );
    }
    let h = 1e-5f32;
    for i in 0..3 * n {
        let finest = levels(&cfg).last().unwrap().resolution as f32;
        let frac = (pts[i] * finest).fract();
        if !(0.01..0.99).contains(&frac) {
            continue; // too close to a cell face of the finest level for a central difference
        }
        let (mut a, mut b) = (pts.clone(), pts.clone());
        a[i] += h;
        b[i] -= h;
        let fd = (loss(&table, &a) - loss(&table, &b)) / (a[i] as f64 - b[i] as f64);
        let err = (dx_fused[i] as f64 - fd).abs() / fd.abs().max(1.0);
        assert!(err < 1e-3, "position {i}: {} vs {fd}", dx_fused[i]);
    }
}

#[test]
fn sparse_adam_moves_only_touched_entries() {
    let cfg = small();
    let dev = Device::flex().autodiff();
    let grid = HashGrid::new(cfg.clone(), 9);
    let before = grid.table();
    let x = Tensor::<2>::from_data(TensorData::new(vec![0.3, 0.3, 0.3], [1, 3]), &dev);
    let _ = grid.encode(x).sum().backward();
    let touched = grid.touched();
    assert!(touched > 0 && touched <= 8 * cfg.levels, "touched {touched}");
    grid.adam_step(&AdamParams::default(), 1e-2);
    let after = grid.table();
    let changed = before.iter().zip(&after).filter(|(a, b)| a != b).count();
    assert!(
        changed > 0 && changed <= touched * cfg.features,
        "changed {changed}"
    );
    assert_eq!(grid.touched(), 0, "gradients cleared after the step");
    assert!(grid.grad().iter().all(|g| *g == 0.0));
}

/// A small space-time grid: spatial resolutions 4 to 64 over five levels.
fn space_time(time_resolution: u32, time_follows_space: bool) -> HashGridConfig {
    HashGridConfig {
        dims: 4,
        levels: 5,
        features: 2,
        log2_table: 12,
        base_resolution: 4,
        finest_resolution: 64,
        time_resolution: Some(time_resolution),
        time_follows_space,
    }
}

#[test]
fn time_resolution_can_follow_the_spatial_resolution() {
    let cfg = space_time(16, true);
    // Spatial resolutions ⌊4·2^l⌋ (4, 7, 15, 31, 63: growth 2 in floating point, floored);
    // time round(16·r/64) = 1, 2, 4, 8, 16.
    let lv = levels(&cfg);
    let time: Vec<u32> = lv.iter().map(|l| l.resolutions[3]).collect();
    let space: Vec<u32> = lv.iter().map(|l| l.resolutions[0]).collect();
    assert!(
        space
            .iter()
            .zip([4, 8, 16, 32, 64])
            .all(|(&r, want)| r == want || r + 1 == want),
        "{space:?}"
    );
    assert_eq!(time, [1, 2, 4, 8, 16]);
    // Same encoding as the f64 definition at those resolutions.
    let n_params = HashGrid::new(cfg.clone(), 0).num_params();
    let table: Vec<f32> = (0..n_params)
        .map(|i| ((i * 104_729) % 997) as f32 / 500.0 - 1.0)
        .collect();
    let grid = HashGrid::with_table(cfg.clone(), table.clone());
    let mut rng = StdRng::seed_from_u64(3);
    let pts: Vec<f32> = (0..4 * 30).map(|_| rng.random_range(0.0..1.0)).collect();
    let fused = grid.encode_host(&pts);
    let width = cfg.output_dim();
    for p in 0..30 {
        let x: Vec<f64> = pts[4 * p..4 * p + 4].iter().map(|v| *v as f64).collect();
        for (j, want) in encode_f64_nd(&cfg, &table, &x).into_iter().enumerate() {
            assert!(
                (fused[p * width + j] as f64 - want).abs() < 1e-4,
                "point {p} feature {j}"
            );
        }
    }
}

#[test]
fn space_time_grid_caps_time_resolution_and_differentiates() {
    let cfg = space_time(7, false);
    let lv = levels(&cfg);
    assert!(
        lv.iter()
            .all(|l| l.resolutions[3] == l.resolution.min(7) && l.resolutions[0] == l.resolution)
    );
    let n_params = HashGrid::new(cfg.clone(), 0).num_params();
    let table: Vec<f32> = (0..n_params)
        .map(|i| ((i * 7_919) % 1000) as f32 / 500.0 - 1.0)
        .collect();
    let grid = HashGrid::with_table(cfg.clone(), table.clone());
    let n = 40;
    let mut rng = StdRng::seed_from_u64(8);
    let pts: Vec<f32> = (0..4 * n).map(|_| rng.random_range(0.0..1.0)).collect();
    let fused = grid.encode_host(&pts);
    let width = cfg.output_dim();
    for p in 0..n {
        let x: Vec<f64> = pts[4 * p..4 * p + 4].iter().map(|v| *v as f64).collect();
        let want = encode_f64_nd(&cfg, &table, &x);
        for j in 0..width {
            assert!(
                (fused[p * width + j] as f64 - want[j]).abs() < 1e-4,
                "point {p} feature {j}"
            );
        }
    }
    // Position gradient (including d/dt) against central differences of the f64 definition.
    let dev = Device::flex().autodiff();
    let upstream: Vec<f32> = (0..n * width).map(|_| rng.random_range(-1.0..1.0)).collect();
    let x = Tensor::<2>::from_data(TensorData::new(pts.clone(), [n, 4]), &dev).require_grad();
    let up = Tensor::<2>::from_data(TensorData::new(upstream.clone(), [n, width]), &dev);
    let g = (grid.encode(x.clone()) * up).sum().backward();
    let dx = host(x.grad(&g).unwrap());
    let finest = lv.last().unwrap().resolutions;
    for p in 0..n {
        for a in 0..4 {
            let frac = (pts[4 * p + a] * finest[a] as f32).fract();
            if !(0.01..0.99).contains(&frac) {
                continue;
            }
            let loss = |delta: f64| -> f64 {
                let mut x: Vec<f64> = pts[4 * p..4 * p + 4].iter().map(|v| *v as f64).collect();
                x[a] += delta;
                encode_f64_nd(&cfg, &table, &x)
                    .iter()
                    .zip(&upstream[p * width..])
                    .map(|(e, u)| e * *u as f64)
                    .sum()
            };
            let h = 1e-6;
            let fd = (loss(h) - loss(-h)) / (2.0 * h);
            assert!(
                (dx[4 * p + a] as f64 - fd).abs() < 1e-3 * fd.abs().max(1.0),
                "point {p} axis {a}: {} vs {fd}",
                dx[4 * p + a]
            );
        }
    }
}

/// The backward pass computes the position gradient in the same sweep as the table gradient
/// when the positions want one: the table gradient must not depend on that, bit for bit, on a
/// 3-D and a 4-D grid with dense and hashed levels.
#[test]
fn table_gradient_is_the_same_with_or_without_a_position_gradient() {
    let dev = Device::flex().autodiff();
    for cfg in [small(), space_time(7, true)] {
        let d = cfg.dims;
        let grid = HashGrid::new(cfg.clone(), 11);
        let n = 300;
        let mut rng = StdRng::seed_from_u64(12);
        let pts: Vec<f32> = (0..d * n).map(|_| rng.random_range(-0.05..1.05)).collect();
        let width = cfg.output_dim();
        let upstream: Vec<f32> = (0..n * width).map(|_| rng.random_range(-1.0..1.0)).collect();
        let table_grad = |want_position: bool| {
            let x = Tensor::<2>::from_data(TensorData::new(pts.clone(), [n, d]), &dev);
            let x = if want_position { x.require_grad() } else { x };
            let up = Tensor::<2>::from_data(TensorData::new(upstream.clone(), [n, width]), &dev);
            let g = (grid.encode(x.clone()) * up).sum().backward();
            assert_eq!(x.grad(&g).is_some(), want_position);
            let out = grid.grad();
            grid.zero_grad();
            out
        };
        let with = table_grad(true);
        let without = table_grad(false);
        assert!(with.iter().any(|v| *v != 0.0));
        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&with), bits(&without), "{cfg:?}");
    }
}
