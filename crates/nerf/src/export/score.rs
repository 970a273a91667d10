//! Exported geometry against the truth, for scenes our generator made (`scene.json`):
//! accuracy (distance from each exported point to the nearest true surface) and completeness
//! (distance from the surfaces the test views see to the nearest exported point).

use std::collections::HashMap;

use nerf_synth::{Scene, Split};

/// Accuracy and completeness of exported points, distances in scene units.
#[derive(Clone, Debug, serde::Serialize)]
pub struct GeometryScore {
    /// The longest side of the scene box; `tolerance` is 1 % of it.
    pub scene_size: f64,
    pub tolerance: f64,
    pub points: usize,
    /// Mean and median distance from exported points to the true surfaces.
    pub accuracy_mean: f64,
    pub accuracy_median: f64,
    /// Share of exported points within `tolerance` of a true surface.
    pub accuracy_within: f64,
    /// Surface points seen by the test views (pixel-centre rays, every `stride`-th pixel).
    pub reference_points: usize,
    /// Mean distance from those to the nearest exported point (capped at 5 % of the scene size).
    pub completeness_mean: f64,
    /// Share of them with an exported point within `tolerance`.
    pub completeness_within: f64,
    /// Symmetric Chamfer distance: (accuracy_mean + completeness_mean) / 2.
    pub chamfer: f64,
}

/// Scores `points` against `scene` at time τ; `scene_size` sets the tolerance (1 %).
pub fn score(scene: &Scene, time: f64, points: &[[f32; 3]], scene_size: f64) -> GeometryScore {
    let tolerance = 0.01 * scene_size;
    let mut acc: Vec<f64> = points
        .iter()
        .map(|p| scene.surface_distance(p.map(f64::from), time))
        .collect();
    acc.sort_by(f64::total_cmp);
    let n = acc.len().max(1) as f64;
    let accuracy_mean = acc.iter().sum::<f64>() / n;
    let accuracy_median = acc.get(acc.len() / 2).copied().unwrap_or(f64::NAN);
    let accuracy_within = acc.iter().filter(|&&d| d <= tolerance).count() as f64 / n;

    let reference = visible_surface(scene, time, 4);
    let cap = 5.0 * tolerance;
    let index = NearestIndex::new(points, 2.0 * tolerance);
    let comp: Vec<f64> = reference.iter().map(|p| index.distance(*p, cap)).collect();
    let m = comp.len().max(1) as f64;
    let completeness_mean = comp.iter().sum::<f64>() / m;
    let completeness_within = comp.iter().filter(|&&d| d <= tolerance).count() as f64 / m;
    GeometryScore {
        scene_size,
        tolerance,
        points: points.len(),
        accuracy_mean,
        accuracy_median,
        accuracy_within,
        reference_points: reference.len(),
        completeness_mean,
        completeness_within,
        chamfer: 0.5 * (accuracy_mean + completeness_mean),
    }
}

/// Hits of the test views' pixel-centre rays (every `stride`-th pixel in each direction) at τ.
fn visible_surface(scene: &Scene, time: f64, stride: u32) -> Vec<[f64; 3]> {
    let mut out = Vec::new();
    for view in scene.views_in(Split::Test) {
        let camera = scene.camera(view);
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        for j in (0..h).step_by(stride as usize) {
            for i in (0..w).step_by(stride as usize) {
                let d = camera.pixel_direction(i, j);
                if let Some(hit) = scene.intersect(camera.pose.translation, d, time) {
                    out.push(hit.point);
                }
            }
        }
    }
    out
}

/// Points bucketed in cubic cells, for nearest-point distances up to a cap.
struct NearestIndex<'a> {
    points: &'a [[f32; 3]],
    cell: f64,
    cells: HashMap<[i64; 3], Vec<u32>>,
}

impl<'a> NearestIndex<'a> {
    fn new(points: &'a [[f32; 3]], cell: f64) -> Self {
        let mut cells: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (k, p) in points.iter().enumerate() {
            cells
                .entry(Self::key(p.map(f64::from), cell))
                .or_default()
                .push(k as u32);
        }
        NearestIndex { points, cell, cells }
    }

    fn key(p: [f64; 3], cell: f64) -> [i64; 3] {
        p.map(|x| (x / cell).floor() as i64)
    }

    /// Distance from `p` to the nearest point, or `cap` when none is that close.
    fn distance(&self, p: [f64; 3], cap: f64) -> f64 {
        let c = Self::key(p, self.cell);
        let r = (cap / self.cell).ceil() as i64;
        let mut best = cap * cap;
        for dz in -r..=r {
            for dy in -r..=r {
                for dx in -r..=r {
                    let Some(bucket) = self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) else {
                        continue;
                    };
                    for &k in bucket {
                        let q = self.points[k as usize];
                        let d2: f64 = (0..3).map(|a| (p[a] - q[a] as f64).powi(2)).sum();
                        best = best.min(d2);
                    }
                }
            }
        }
        best.sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_index_matches_brute_force() {
        let points: Vec<[f32; 3]> = (0..500)
            .map(|k| {
                let t = k as f32 * 0.37;
                [t.sin(), (1.3 * t).cos(), (0.7 * t).sin() * 0.5]
            })
            .collect();
        let index = NearestIndex::new(&points, 0.05);
        for k in 0..200 {
            let t = k as f64 * 0.91;
            let p = [t.cos() * 1.1, (0.4 * t).sin(), (2.1 * t).cos() * 0.6];
            let brute = points
                .iter()
                .map(|q| (0..3).map(|a| (p[a] - q[a] as f64).powi(2)).sum::<f64>().sqrt())
                .fold(f64::INFINITY, f64::min);
            let got = index.distance(p, 0.2);
            assert!((got - brute.min(0.2)).abs() < 1e-6, "{got} vs {brute}");
        }
    }

    #[test]
    fn the_true_surface_scores_zero_and_distant_points_fail() {
        let cfg = nerf_synth::SynthConfig::new(nerf_synth::Preset::Static)
            .with_size(24, 24)
            .with_views(4, 2);
        let scene = Scene::from_config(&cfg);
        let truth: Vec<[f32; 3]> = visible_surface(&scene, 0.0, 1)
            .iter()
            .map(|p| p.map(|x| x as f32))
            .collect();
        assert!(truth.len() > 500, "{} surface points", truth.len());
        let s = score(&scene, 0.0, &truth, 4.0);
        assert!(s.accuracy_mean < 1e-5 && s.accuracy_within == 1.0, "{s:?}");
        assert!(
            s.completeness_mean < 1e-5 && s.completeness_within == 1.0,
            "{s:?}"
        );
        // Half of the surface (x > median) missing: completeness falls, accuracy stays.
        let mut xs: Vec<f32> = truth.iter().map(|p| p[0]).collect();
        xs.sort_by(f32::total_cmp);
        let half: Vec<[f32; 3]> = truth
            .iter()
            .filter(|p| p[0] <= xs[xs.len() / 2])
            .copied()
            .collect();
        let s = score(&scene, 0.0, &half, 4.0);
        assert!(s.accuracy_within == 1.0 && s.completeness_within < 0.7, "{s:?}");
        // Everything far off: nothing accurate, nothing complete.
        let off: Vec<[f32; 3]> = truth.iter().map(|p| [p[0], p[1], p[2] + 50.0]).collect();
        let s = score(&scene, 0.0, &off, 4.0);
        assert!(s.accuracy_within == 0.0 && s.completeness_within == 0.0, "{s:?}");
        assert!((s.completeness_mean - 0.2).abs() < 1e-9, "capped at 5 %: {s:?}");
    }
}
