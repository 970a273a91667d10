//! Samplers: bounds, ordering, degenerate weights, and marching through an occupancy grid.

use nerf_core::occupancy::{OccupancyConfig, OccupancyGrid};
use nerf_core::rays::Rays;
use nerf_core::sampler::{MarchConfig, RaySamples, Spacing, march, sample_pdf, stratified};
use proptest::prelude::*;
use rand::{SeedableRng, rngs::StdRng};

fn check_sorted_inside(s: &RaySamples, near: f32, far: f32) {
    for r in 0..s.num_rays() {
        let range = s.range(r);
        for i in range.clone() {
            assert!(
                s.t_start[i] >= near - 1e-5 && s.t_end[i] <= far + 1e-5,
                "outside [{near}, {far}]"
            );
            assert!(
                s.t_start[i] <= s.t[i] && s.t[i] <= s.t_end[i],
                "evaluation point outside its interval"
            );
            assert!(s.t[i].is_finite());
        }
        for i in range.start + 1..range.end {
            assert!(s.t[i] >= s.t[i - 1], "not sorted");
            assert!(
                (s.t_start[i] - s.t_end[i - 1]).abs() < 1e-5,
                "intervals not contiguous"
            );
        }
    }
}

#[test]
fn stratified_partitions_near_far() {
    let mut rng = StdRng::seed_from_u64(1);
    for spacing in [Spacing::Depth, Spacing::Disparity] {
        let s = stratified(&[2.0; 5], &[6.0; 5], 64, spacing, Some(&mut rng));
        check_sorted_inside(&s, 2.0, 6.0);
        for r in 0..5 {
            let range = s.range(r);
            assert_eq!(range.len(), 64);
            assert_eq!(s.t_start[range.start], 2.0);
            assert_eq!(s.t_end[range.end - 1], 6.0);
        }
    }
    let det = stratified(&[0.0], &[1.0], 4, Spacing::Depth, None::<&mut StdRng>);
    assert_eq!(det.t, vec![0.125, 0.375, 0.625, 0.875]);
}

fn coarse(n: usize) -> RaySamples {
    stratified(&[2.0], &[6.0], n, Spacing::Depth, None::<&mut StdRng>)
}

#[test]
fn pdf_with_zero_spike_and_uniform_weights() {
    let c = coarse(32);
    let mut rng = StdRng::seed_from_u64(2);
    // All zero: samples spread uniformly over the bins.
    let z = sample_pdf(&c, &[0.0; 32], 64, Some(&mut rng));
    check_sorted_inside(&z, 2.0, 6.0);
    assert_eq!(z.num_samples(), 64 + 32);
    let mid = z.t.iter().filter(|t| **t < 4.0).count() as f32 / z.num_samples() as f32;
    assert!(
        (mid - 0.5).abs() < 0.1,
        "all-zero weights should sample uniformly, got {mid}"
    );
    // One spike: the new points fall inside that bin.
    let mut w = vec![0.0; 32];
    w[10] = 1.0;
    let spike = sample_pdf(&c, &w, 64, None::<&mut StdRng>);
    check_sorted_inside(&spike, 2.0, 6.0);
    let (lo, hi) = (c.t_start[10], c.t_end[10]);
    let inside = spike.t.iter().filter(|t| **t >= lo && **t <= hi).count();
    assert!(
        inside >= 60,
        "only {inside} samples in the spike bin [{lo}, {hi}]"
    );
    // Uniform weights behave like all-zero ones.
    let u = sample_pdf(&c, &[0.5; 32], 64, None::<&mut StdRng>);
    check_sorted_inside(&u, 2.0, 6.0);
    // Garbage weights (NaN, negative, infinite) are treated as zero, not propagated.
    let mut bad = vec![0.1; 32];
    bad[3] = f32::NAN;
    bad[4] = -5.0;
    bad[5] = f32::INFINITY;
    let b = sample_pdf(&c, &bad, 64, Some(&mut rng));
    check_sorted_inside(&b, 2.0, 6.0);
}

proptest! {
    #[test]
    fn pdf_samples_stay_sorted_and_inside(
        weights in prop::collection::vec(0.0f32..10.0, 1..48),
        near in 0.0f32..3.0,
        len in 0.01f32..10.0,
        n in 1usize..96,
        seed in any::<u64>(),
        sparsity in 0.0f64..1.0,
    ) {
        let k = weights.len();
        let far = near + len;
        let c = stratified(&[near], &[far], k, Spacing::Depth, None::<&mut StdRng>);
        // Zero out a random share of the weights to get spiky distributions.
        let mut rng = StdRng::seed_from_u64(seed);
        let w: Vec<f32> = weights.iter().map(|&v| if rand::Rng::random::<f64>(&mut rng) < sparsity { 0.0 } else { v }).collect();
        let s = sample_pdf(&c, &w, n, Some(&mut rng));
        prop_assert_eq!(s.num_samples(), n + k);
        check_sorted_inside(&s, near, far);
    }
}

#[test]
fn marching_skips_empty_cells_and_keeps_occupied_ones() {
    let aabb = [[-1.0f32; 3], [1.0; 3]];
    let mut grid = OccupancyGrid::new(
        OccupancyConfig {
            resolution: 16,
            ..Default::default()
        },
        aabb,
    );
    let mut rng = StdRng::seed_from_u64(3);
    // A slab |z| < 0.25 is solid.
    grid.update(0, 0.01, &mut rng, &mut |p: &[f32]| {
        p.chunks(3)
            .map(|q| if q[2].abs() < 0.25 { 50.0 } else { 0.0 })
            .collect()
    });
    let mut rays = Rays::default();
    rays.push([0.1, 0.2, 3.0], [0.0, 0.0, -1.0]);
    rays.push([5.0, 5.0, 5.0], [0.0, 0.0, -1.0]); // misses the box
    let cfg = MarchConfig {
        step: 0.01,
        cone_angle: 0.0,
        max_step: 1.0,
        max_samples: 1024,
    };
    let full = march(&rays, aabb, 0.0, 10.0, None, &cfg, None::<&mut StdRng>);
    let skip = march(&rays, aabb, 0.0, 10.0, Some(&grid), &cfg, None::<&mut StdRng>);
    assert_eq!(full.range(0).len(), 200, "2 units at step 0.01");
    assert!(full.range(1).is_empty() && skip.range(1).is_empty());
    let kept = skip.range(0).len();
    assert!(
        (45..=70).contains(&kept),
        "kept {kept} samples, slab covers ~50 steps (plus cell rounding)"
    );
    for i in skip.range(0) {
        let z = 3.0 - skip.t[i];
        assert!(
            z.abs() < 0.25 + 2.0 / 16.0,
            "sample at z = {z} outside the occupied cells"
        );
    }
    check_sorted_inside(&full, 2.0, 4.0);
}
