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
    /// pixels in at least `min_views` views. `project(view, p)` returns whether `p` lands on
    /// background in that view (`Some(true)`), on foreground (`Some(false)`), or outside it
    /// (`None`). The caller dilates its foreground masks by a cell's projected size, so a cell
    /// is only carved when no part of it can be seen in front of background. Returns the
    /// fraction of cells carved.
    pub fn carve(
        &mut self,
        views: usize,
        min_views: usize,
        project: &(dyn Fn(usize, [f32; 3]) -> Option<bool> + Sync),
    ) -> f32 {
        use rayon::prelude::*;
        let centers: Vec<[f32; 3]> = (0..self.num_cells()).map(|i| self.cell_center(i)).collect();
        let carved: Vec<bool> = centers
            .par_iter()
            .map(|&p| {
                (0..views)
                    .filter(|&v| project(v, p) == Some(true))
                    .take(min_views)
                    .count()
                    >= min_views
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

/// Carves the visual hull of an object dataset into `grid`: a cell is empty when, in at least two
/// of the given views, the whole window its cell covers on screen shows background (alpha below
/// 0.01, or exactly the background colour where the images have no alpha). Does nothing for
/// scenes without a background (real captures) or in NDC space. Returns the carved fraction.
pub fn carve_visual_hull(grid: &mut OccupancyGrid, dataset: &nerf_data::Dataset, views: &[usize]) -> f32 {
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
        // Pixel radius of the cell's bounding sphere, plus one pixel of slack.
        let r = (cam.intrinsics.fx.max(cam.intrinsics.fy) * half_diag / depth).ceil() + 1.0;
        let t = &tables[k];
        let (x0, y0, x1, y1) = ((u - r).floor(), (v - r).floor(), (u + r).ceil(), (v + r).ceil());
        if x0 < 0.0 || y0 < 0.0 || x1 > t.width as f64 || y1 > t.height as f64 || depth <= half_diag {
            return None;
        }
        Some(t.count(x0 as usize, y0 as usize, x1 as usize, y1 as usize) == 0)
    };
    grid.carve(views.len(), 2, &project)
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
