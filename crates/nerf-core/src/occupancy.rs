//! Occupancy grid: a coarse density cache over the scene box that lets the marcher skip empty
//! space (Instant-NGP / nerfacc).
//!
//! Each cell keeps a running value v ← max(decay·v, σ(x)·step) for a random point x in the cell
//! (σ·step approximates the opacity of one marching step). A cell is occupied when v exceeds
//! min(threshold, mean of the positive values); the occupied set is kept as a bitfield.

use rand::Rng;

/// Occupancy-grid settings (nerfacc defaults, except a coarser grid suited to the CPU).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct OccupancyConfig {
    /// Cells per axis.
    pub resolution: u32,
    /// Update every this many training steps.
    pub update_every: usize,
    pub decay: f32,
    /// Opacity-per-step threshold.
    pub threshold: f32,
    /// Steps during which every cell is refreshed on each update.
    pub warmup_steps: usize,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        OccupancyConfig {
            resolution: 64,
            update_every: 16,
            decay: 0.95,
            threshold: 0.01,
            warmup_steps: 256,
        }
    }
}

/// Which views must see background through a cell for visual-hull carving to empty it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HullRule {
    /// Background in at least this many views: in a still scene one view's background already
    /// proves a cell empty (more guard against a stray alpha).
    AtLeast(usize),
    /// Foreground in no view that sees any of the cell, and background in at least
    /// `min_background` views: where things move, a view's background proves a cell empty at
    /// that view's time only, so the cell must look empty at every time the video saw it (a
    /// mover that passes through it shows in front of something in that frame). With
    /// `min_background` 0 the cells no view sees are carved too (instant-ngp's untrained
    /// cells): nothing was observed there, and a field's guess there shows as floaters from new
    /// viewpoints.
    NoForeground { min_background: usize },
}

#[derive(Clone, Debug, PartialEq)]
pub struct OccupancyGrid {
    pub config: OccupancyConfig,
    /// Scene box `[min, max]`.
    pub aabb: [[f32; 3]; 2],
    values: Vec<f32>,
    bits: Vec<u64>,
    /// Cells proven empty by the images (visual hull); never marked occupied again.
    carved: Vec<bool>,
}

impl OccupancyGrid {
    /// A grid that starts fully occupied, so the first steps sample everywhere.
    pub fn new(config: OccupancyConfig, aabb: [[f32; 3]; 2]) -> Self {
        let n = (config.resolution as usize).pow(3);
        OccupancyGrid {
            config,
            aabb,
            values: vec![0.0; n],
            bits: vec![u64::MAX; n.div_ceil(64)],
            carved: vec![false; n],
        }
    }

    pub fn num_cells(&self) -> usize {
        self.values.len()
    }

    /// Edge lengths of one cell.
    pub fn cell_size(&self) -> [f32; 3] {
        let r = self.config.resolution as f32;
        [0, 1, 2].map(|a| (self.aabb[1][a] - self.aabb[0][a]) / r)
    }

    /// Integer cell coordinates of a point, or `None` outside the box.
    pub fn cell_coords(&self, p: [f32; 3]) -> Option<[u32; 3]> {
        let r = self.config.resolution;
        let mut c = [0u32; 3];
        for a in 0..3 {
            let (lo, hi) = (self.aabb[0][a], self.aabb[1][a]);
            let u = (p[a] - lo) / (hi - lo);
            if !(0.0..=1.0).contains(&u) {
                return None; // also rejects NaN
            }
            c[a] = ((u * r as f32) as u32).min(r - 1);
        }
        Some(c)
    }

    fn index(&self, c: [u32; 3]) -> usize {
        let r = self.config.resolution as usize;
        (c[2] as usize * r + c[1] as usize) * r + c[0] as usize
    }

    pub fn is_occupied(&self, p: [f32; 3]) -> bool {
        self.cell_coords(p).is_some_and(|c| self.bit(self.index(c)))
    }

    fn bit(&self, i: usize) -> bool {
        self.bits[i / 64] >> (i % 64) & 1 == 1
    }

    /// Fraction of occupied cells.
    pub fn occupied_fraction(&self) -> f32 {
        let n: u32 = self.bits.iter().map(|w| w.count_ones()).sum();
        n.min(self.num_cells() as u32) as f32 / self.num_cells() as f32
    }

    /// Whether `step` is an update step.
    pub fn due(&self, step: usize) -> bool {
        step.is_multiple_of(self.config.update_every.max(1))
    }

    /// Refreshes the grid at training step `step`: during warm-up every cell, afterwards a
    /// quarter of the cells at random plus up to a quarter of the occupied ones (carved cells
    /// excluded). `density`
    /// maps `[M, 3]` world positions to M densities; `step_size` is the marching step length.
    pub fn update(
        &mut self,
        step: usize,
        step_size: f32,
        rng: &mut impl Rng,
        density: &mut dyn FnMut(&[f32]) -> Vec<f32>,
    ) {
        // Carved cells are known empty: never spend density queries on them.
        let live: Vec<usize> = (0..self.num_cells()).filter(|&i| !self.carved[i]).collect();
        let n = live.len();
        let cells: Vec<usize> = if n == 0 {
            Vec::new()
        } else if step < self.config.warmup_steps {
            live
        } else {
            let mut cells: Vec<usize> = (0..n / 4).map(|_| live[rng.random_range(0..n)]).collect();
            let occupied: Vec<usize> = live.iter().copied().filter(|&i| self.bit(i)).collect();
            if !occupied.is_empty() {
                cells.extend(
                    (0..(n / 4).min(occupied.len())).map(|_| occupied[rng.random_range(0..occupied.len())]),
                );
            }
            cells
        };
        let r = self.config.resolution as usize;
        let size = self.cell_size();
        let mut points = Vec::with_capacity(3 * cells.len());
        for &i in &cells {
            let c = [i % r, (i / r) % r, i / (r * r)];
            for a in 0..3 {
                points.push(self.aabb[0][a] + (c[a] as f32 + rng.random::<f32>()) * size[a]);
            }
        }
        // Decay everything once, then raise the refreshed cells (a cell drawn twice keeps the max).
        for v in self.values.iter_mut() {
            *v *= self.config.decay;
        }
        let sigma = density(&points);
        for (&i, &s) in cells.iter().zip(&sigma) {
            let occ = if s.is_finite() {
                (s * step_size).max(0.0)
            } else {
                0.0
            };
            self.values[i] = self.values[i].max(occ);
        }
        self.rebuild_bits();
    }

    fn rebuild_bits(&mut self) {
        let (sum, count) = self
            .values
            .iter()
            .filter(|v| **v > 0.0)
            .fold((0.0f64, 0usize), |(s, c), v| (s + *v as f64, c + 1));
        let mean = if count > 0 {
            (sum / count as f64) as f32
        } else {
            0.0
        };
        let thresh = self.config.threshold.min(mean);
        self.bits.iter_mut().for_each(|w| *w = 0);
        for (i, v) in self.values.iter().enumerate() {
            if *v > thresh && !self.carved[i] {
                self.bits[i / 64] |= 1 << (i % 64);
            }
        }
    }

    /// Values and bits for checkpoints.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// Restores saved values (and re-derives the bitfield).
    pub fn set_values(&mut self, values: Vec<f32>) {
        assert_eq!(values.len(), self.values.len());
        self.values = values;
        self.rebuild_bits();
    }

    /// Centre of cell `i` in world coordinates.
    pub fn cell_center(&self, i: usize) -> [f32; 3] {
        let r = self.config.resolution as usize;
        let c = [i % r, (i / r) % r, i / (r * r)];
        let size = self.cell_size();
        [0, 1, 2].map(|a| self.aabb[0][a] + (c[a] as f32 + 0.5) * size[a])
    }

    /// Visual-hull carving: marks as empty every cell whose centre projects onto background
    /// pixels in the views `rule` asks for. `project(view, p)` returns whether `p` lands on
    /// background in that view (`Some(true)`), on foreground (`Some(false)`), or outside it
    /// (`None`). The caller dilates its foreground masks by a cell's projected size, so a cell
    /// is only carved when no part of it can be seen in front of background. Returns the
    /// fraction of cells carved.
    pub fn carve(
        &mut self,
        views: usize,
        rule: HullRule,
        project: &(dyn Fn(usize, [f32; 3]) -> Option<bool> + Sync),
    ) -> f32 {
        use rayon::prelude::*;
        let centers: Vec<[f32; 3]> = (0..self.num_cells()).map(|i| self.cell_center(i)).collect();
        let carved: Vec<bool> = centers
            .par_iter()
            .map(|&p| match rule {
                HullRule::AtLeast(min_views) => {
                    (0..views)
                        .filter(|&v| project(v, p) == Some(true))
                        .take(min_views)
                        .count()
                        >= min_views
                }
                HullRule::NoForeground { min_background } => {
                    let mut background = 0;
                    for v in 0..views {
                        match project(v, p) {
                            Some(true) => background += 1,
                            Some(false) => return false,
                            None => {}
                        }
                    }
                    background >= min_background
                }
            })
            .collect();
        for (c, new) in self.carved.iter_mut().zip(&carved) {
            *c |= *new;
        }
        for (i, &c) in self.carved.iter().enumerate() {
            if c {
                self.bits[i / 64] &= !(1 << (i % 64));
                self.values[i] = 0.0;
            }
        }
        carved.iter().filter(|c| **c).count() as f32 / carved.len().max(1) as f32
    }

    /// Which cells the images proved empty (for checkpoints).
    pub fn carved(&self) -> &[bool] {
        &self.carved
    }

    pub fn set_carved(&mut self, carved: Vec<bool>) {
        assert_eq!(carved.len(), self.carved.len());
        self.carved = carved;
        self.rebuild_bits();
    }

    /// The cells occupied in any of `grids` (all of one resolution and box), each with the
    /// largest of their values; `None` for no grids. Never updated itself: rebuilt from them.
    pub fn union_of(grids: &[OccupancyGrid]) -> Option<OccupancyGrid> {
        let mut union = grids.first()?.clone();
        for g in &grids[1..] {
            assert_eq!(g.values.len(), union.values.len(), "grids of one resolution");
            for (u, v) in union.values.iter_mut().zip(&g.values) {
                *u = u.max(*v);
            }
            for (u, b) in union.bits.iter_mut().zip(&g.bits) {
                *u |= *b;
            }
            for (u, c) in union.carved.iter_mut().zip(&g.carved) {
                *u &= *c;
            }
        }
        Some(union)
    }

    /// Distance along unit direction `u` from `p` (inside the box) to the exit of its cell.
    pub fn cell_exit(&self, p: [f32; 3], u: [f32; 3]) -> f32 {
        let size = self.cell_size();
        let mut best = f32::INFINITY;
        for a in 0..3 {
            if u[a] == 0.0 {
                continue;
            }
            let rel = (p[a] - self.aabb[0][a]) / size[a];
            let cell = rel.floor();
            let boundary = if u[a] > 0.0 { cell + 1.0 } else { cell };
            let t = (boundary - rel) * size[a] / u[a];
            if t > 0.0 {
                best = best.min(t);
            }
        }
        best
    }
}

/// Per-view foreground masks as summed-area tables, for O(1) "any foreground in this window".
struct ForegroundTable {
    width: usize,
    height: usize,
    /// `(W + 1) × (H + 1)` prefix sums of the foreground indicator.
    sums: Vec<u32>,
}

impl ForegroundTable {
    fn new(width: usize, height: usize, foreground: impl Fn(usize) -> bool) -> Self {
        let mut sums = vec![0u32; (width + 1) * (height + 1)];
        for y in 0..height {
            let mut row = 0u32;
            for x in 0..width {
                row += u32::from(foreground(y * width + x));
                sums[(y + 1) * (width + 1) + x + 1] = sums[y * (width + 1) + x + 1] + row;
            }
        }
        ForegroundTable { width, height, sums }
    }

    /// Foreground pixels in columns x0..x1, rows y0..y1 (exclusive ends).
    fn count(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> u32 {
        let w = self.width + 1;
        self.sums[y1 * w + x1] + self.sums[y0 * w + x0] - self.sums[y0 * w + x1] - self.sums[y1 * w + x0]
    }
}

/// Carves the visual hull of an object dataset into `grid`: a cell is empty when, in the views
/// `rule` asks for among the given ones, the whole window its cell covers on screen shows
/// background (alpha below 0.01, or exactly the background colour where the images have no
/// alpha). A window that any foreground pixel reaches, even one cut by the image's edge, counts
/// as foreground. Does nothing for scenes without a background (real captures) or in NDC space.
/// Returns the carved fraction.
pub fn carve_visual_hull(
    grid: &mut OccupancyGrid,
    dataset: &nerf_data::Dataset,
    views: &[usize],
    rule: HullRule,
) -> f32 {
    let Some(bg) = dataset.background else { return 0.0 };
    if dataset.ndc.is_some() {
        return 0.0;
    }
    let tables: Vec<ForegroundTable> = views
        .iter()
        .map(|&v| {
            let view = &dataset.views[v];
            let (w, h) = (view.image.width as usize, view.image.height as usize);
            match &view.alpha {
                Some(alpha) => ForegroundTable::new(w, h, |i| alpha[i] >= 0.01),
                None => ForegroundTable::new(w, h, |i| {
                    view.image
                        .pixel(i)
                        .iter()
                        .zip(bg)
                        .any(|(c, b)| (c - b).abs() > 0.5 / 255.0)
                }),
            }
        })
        .collect();
    let size = grid.cell_size();
    let half_diag = 0.5 * (size[0] * size[0] + size[1] * size[1] + size[2] * size[2]).sqrt() as f64;
    let project = |k: usize, p: [f32; 3]| -> Option<bool> {
        let cam = &dataset.views[views[k]].camera;
        let (u, v, depth) = cam.project(p.map(f64::from))?;
        if depth <= half_diag {
            return None;
        }
        // Pixel radius of the cell's bounding sphere, plus one pixel of slack.
        let r = (cam.intrinsics.fx.max(cam.intrinsics.fy) * half_diag / depth).ceil() + 1.0;
        let t = &tables[k];
        let (x0, y0, x1, y1) = ((u - r).floor(), (v - r).floor(), (u + r).ceil(), (v + r).ceil());
        let (w, h) = (t.width as f64, t.height as f64);
        let clip = |a: f64, hi: f64| a.clamp(0.0, hi) as usize;
        let (cx0, cy0, cx1, cy1) = (clip(x0, w), clip(y0, h), clip(x1, w), clip(y1, h));
        let foreground = cx0 < cx1 && cy0 < cy1 && t.count(cx0, cy0, cx1, cy1) > 0;
        let inside = x0 >= 0.0 && y0 >= 0.0 && x1 <= w && y1 <= h;
        match (foreground, inside) {
            (true, _) => Some(false),
            (false, true) => Some(true),
            (false, false) => None,
        }
    };
    grid.carve(views.len(), rule, &project)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{SeedableRng, rngs::StdRng};

    #[test]
    fn update_marks_dense_cells_only() {
        let mut g = OccupancyGrid::new(
            OccupancyConfig {
                resolution: 16,
                ..Default::default()
            },
            [[-1.0; 3], [1.0; 3]],
        );
        assert_eq!(g.occupied_fraction(), 1.0);
        let mut rng = StdRng::seed_from_u64(0);
        // A solid ball of radius 0.5.
        let mut ball = |p: &[f32]| -> Vec<f32> {
            p.chunks(3)
                .map(|q| {
                    if q.iter().map(|v| v * v).sum::<f32>() < 0.25 {
                        100.0
                    } else {
                        0.0
                    }
                })
                .collect()
        };
        g.update(0, 0.01, &mut rng, &mut ball);
        assert!(g.is_occupied([0.0, 0.0, 0.0]));
        assert!(!g.is_occupied([0.9, 0.9, 0.9]));
        assert!(!g.is_occupied([2.0, 0.0, 0.0]), "outside the box");
        let f = g.occupied_fraction();
        let ball_fraction = 4.0 / 3.0 * std::f32::consts::PI * 0.125 / 8.0;
        assert!(
            f > 0.5 * ball_fraction && f < 2.0 * ball_fraction,
            "{f} vs {ball_fraction}"
        );
    }

    /// Four views, each saying of a cell (by the sign of its x and y): `x < 0` is seen as
    /// background by views 0 and 1; `x > 0, y < 0` is seen as foreground by view 2 and as
    /// background by views 0 and 1; `x > 0, y > 0` is outside every view.
    fn four_views(v: usize, p: [f32; 3]) -> Option<bool> {
        match (p[0] < 0.0, p[1] < 0.0, v) {
            (true, _, 0 | 1) => Some(true),
            (true, _, _) => None,
            (false, true, 0 | 1) => Some(true),
            (false, true, 2) => Some(false),
            _ => None,
        }
    }

    #[test]
    fn hull_rules_carve_what_they_say() {
        let grid = || {
            OccupancyGrid::new(
                OccupancyConfig {
                    resolution: 4,
                    ..Default::default()
                },
                [[-1.0; 3], [1.0; 3]],
            )
        };
        let carved_at = |g: &OccupancyGrid, p: [f32; 3]| !g.is_occupied(p);
        let (left, fore, unseen) = ([-0.5, 0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0]);

        // A still scene: two views of background are enough, whatever a third says.
        let mut g = grid();
        let f = g.carve(4, HullRule::AtLeast(2), &four_views);
        assert_eq!(f, 0.75, "x < 0 and x > 0, y < 0");
        assert!(carved_at(&g, left) && carved_at(&g, fore) && !carved_at(&g, unseen));

        // Where things move, one view of foreground keeps the cell.
        let mut g = grid();
        g.carve(4, HullRule::NoForeground { min_background: 2 }, &four_views);
        assert!(carved_at(&g, left) && !carved_at(&g, fore) && !carved_at(&g, unseen));

        // With no background asked for, the cells no view sees go too.
        let mut g = grid();
        g.carve(4, HullRule::NoForeground { min_background: 0 }, &four_views);
        assert!(carved_at(&g, left) && !carved_at(&g, fore) && carved_at(&g, unseen));
        assert!(g.carved()[g.num_cells() - 1], "the carved cells are remembered");
    }

    /// Three 48×48 RGBA views of a ball of radius 0.4, from cameras at radius 4 on a 60° arc:
    /// at the origin in views 0 and 1, moved to `moved` in view 2 (a mover at a later time).
    /// The alpha comes from ray-ball intersection, independent of the carve's projection.
    fn ball_video(moved: [f64; 3]) -> nerf_data::Dataset {
        use nerf_data::camera::{Camera, Intrinsics, Pose};
        let mut ds =
            nerf_data::Dataset::blender_object("ball".into(), nerf_data::Format::DNerf, [1.0; 3], Vec::new());
        let (w, h, radius) = (48u32, 48u32, 0.4f64);
        for (k, deg) in [-30.0f64, 0.0, 30.0].into_iter().enumerate() {
            let a = deg.to_radians();
            let eye = [4.0 * a.cos(), 4.0 * a.sin(), 0.5];
            let camera = Camera::new(
                Intrinsics::from_fov_x(0.6, w, h),
                Pose::look_at(eye, [0.0; 3], [0.0, 0.0, 1.0]),
            );
            let centre = if k == 2 { moved } else { [0.0; 3] };
            let alpha: Vec<f32> = (0..w * h)
                .map(|p| {
                    let d = camera.pixel_direction(p % w, p / w);
                    let o: Vec<f64> = (0..3).map(|i| eye[i] - centre[i]).collect();
                    let (dd, od) = (
                        d.iter().map(|x| x * x).sum::<f64>(),
                        d.iter().zip(&o).map(|(a, b)| a * b).sum::<f64>(),
                    );
                    let oo = o.iter().map(|x| x * x).sum::<f64>();
                    f32::from(od * od - dd * (oo - radius * radius) > 0.0)
                })
                .collect();
            let mut image = nerf_data::Image::new(w, h, 3);
            image.data.fill(1.0);
            ds.views.push(nerf_data::View {
                name: format!("r_{k}"),
                image,
                alpha: Some(alpha),
                camera,
                time: Some(k as f32 / 2.0),
            });
        }
        ds.train = vec![0, 1, 2];
        ds
    }

    #[test]
    fn a_mover_keeps_its_cells_where_a_still_scene_would_lose_them() {
        let moved = [0.0, 0.9, 0.0];
        let ds = ball_video(moved);
        let grid = || {
            OccupancyGrid::new(
                OccupancyConfig {
                    resolution: 32,
                    ..Default::default()
                },
                ds.aabb,
            )
        };
        let occupied = |g: &OccupancyGrid, p: [f64; 3]| g.is_occupied(p.map(|v| v as f32));
        let (ball, mover, empty, unseen) = ([0.0; 3], moved, [0.0, -0.9, 0.0], [1.4, 0.0, 1.4]);

        let mut still = grid();
        let f = carve_visual_hull(&mut still, &ds, &ds.train, HullRule::AtLeast(2));
        assert!(f > 0.0);
        assert!(occupied(&still, ball), "seen in front of the ball by every view");
        assert!(
            !occupied(&still, mover),
            "background in views 0 and 1: gone, mover or not"
        );
        assert!(!occupied(&still, empty));
        assert!(occupied(&still, unseen), "no view says anything of it");

        let mut moving = grid();
        carve_visual_hull(
            &mut moving,
            &ds,
            &ds.train,
            HullRule::NoForeground { min_background: 2 },
        );
        assert!(
            occupied(&moving, ball) && occupied(&moving, mover),
            "view 2 sees the ball there"
        );
        assert!(!occupied(&moving, empty) && occupied(&moving, unseen));

        let mut unseen_too = grid();
        carve_visual_hull(
            &mut unseen_too,
            &ds,
            &ds.train,
            HullRule::NoForeground { min_background: 0 },
        );
        assert!(occupied(&unseen_too, ball) && occupied(&unseen_too, mover));
        assert!(!occupied(&unseen_too, empty) && !occupied(&unseen_too, unseen));
    }

    #[test]
    fn cell_exit_reaches_the_next_boundary() {
        let g = OccupancyGrid::new(
            OccupancyConfig {
                resolution: 4,
                ..Default::default()
            },
            [[0.0; 3], [4.0; 3]],
        );
        let d = g.cell_exit([1.25, 1.5, 1.5], [1.0, 0.0, 0.0]);
        assert!((d - 0.75).abs() < 1e-6);
        let d = g.cell_exit([1.25, 1.5, 1.5], [-1.0, 0.0, 0.0]);
        assert!((d - 0.25).abs() < 1e-6);
    }
}
