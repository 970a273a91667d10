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
        OccupancyConfig { resolution: 64, update_every: 16, decay: 0.95, threshold: 0.01, warmup_steps: 256 }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct OccupancyGrid {
    pub config: OccupancyConfig,
    /// Scene box `[min, max]`.
    pub aabb: [[f32; 3]; 2],
    values: Vec<f32>,
    bits: Vec<u64>,
}

impl OccupancyGrid {
    /// A grid that starts fully occupied, so the first steps sample everywhere.
    pub fn new(config: OccupancyConfig, aabb: [[f32; 3]; 2]) -> Self {
        let n = (config.resolution as usize).pow(3);
        OccupancyGrid { config, aabb, values: vec![0.0; n], bits: vec![u64::MAX; n.div_ceil(64)] }
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
    /// quarter of the cells at random plus up to a quarter of the occupied ones. `density`
    /// maps `[M, 3]` world positions to M densities; `step_size` is the marching step length.
    pub fn update(&mut self, step: usize, step_size: f32, rng: &mut impl Rng, density: &mut dyn FnMut(&[f32]) -> Vec<f32>) {
        let n = self.num_cells();
        let cells: Vec<usize> = if step < self.config.warmup_steps {
            (0..n).collect()
        } else {
            let mut cells: Vec<usize> = (0..n / 4).map(|_| rng.random_range(0..n)).collect();
            let occupied: Vec<usize> = (0..n).filter(|&i| self.bit(i)).collect();
            if !occupied.is_empty() {
                cells.extend((0..(n / 4).min(occupied.len())).map(|_| occupied[rng.random_range(0..occupied.len())]));
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
            let occ = if s.is_finite() { (s * step_size).max(0.0) } else { 0.0 };
            self.values[i] = self.values[i].max(occ);
        }
        self.rebuild_bits();
    }

    fn rebuild_bits(&mut self) {
        let (sum, count) = self.values.iter().filter(|v| **v > 0.0).fold((0.0f64, 0usize), |(s, c), v| (s + *v as f64, c + 1));
        let mean = if count > 0 { (sum / count as f64) as f32 } else { 0.0 };
        let thresh = self.config.threshold.min(mean);
        self.bits.iter_mut().for_each(|w| *w = 0);
        for (i, v) in self.values.iter().enumerate() {
            if *v > thresh {
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{SeedableRng, rngs::StdRng};

    #[test]
    fn update_marks_dense_cells_only() {
        let mut g = OccupancyGrid::new(OccupancyConfig { resolution: 16, ..Default::default() }, [[-1.0; 3], [1.0; 3]]);
        assert_eq!(g.occupied_fraction(), 1.0);
        let mut rng = StdRng::seed_from_u64(0);
        // A solid ball of radius 0.5.
        let mut ball = |p: &[f32]| -> Vec<f32> {
            p.chunks(3).map(|q| if q.iter().map(|v| v * v).sum::<f32>() < 0.25 { 100.0 } else { 0.0 }).collect()
        };
        g.update(0, 0.01, &mut rng, &mut ball);
        assert!(g.is_occupied([0.0, 0.0, 0.0]));
        assert!(!g.is_occupied([0.9, 0.9, 0.9]));
        assert!(!g.is_occupied([2.0, 0.0, 0.0]), "outside the box");
        let f = g.occupied_fraction();
        let ball_fraction = 4.0 / 3.0 * std::f32::consts::PI * 0.125 / 8.0;
        assert!(f > 0.5 * ball_fraction && f < 2.0 * ball_fraction, "{f} vs {ball_fraction}");
    }

    #[test]
    fn cell_exit_reaches_the_next_boundary() {
        let g = OccupancyGrid::new(OccupancyConfig { resolution: 4, ..Default::default() }, [[0.0; 3], [4.0; 3]]);
        let d = g.cell_exit([1.25, 1.5, 1.5], [1.0, 0.0, 0.0]);
        assert!((d - 0.75).abs() < 1e-6);
        let d = g.cell_exit([1.25, 1.5, 1.5], [-1.0, 0.0, 0.0]);
        assert!((d - 0.25).abs() < 1e-6);
    }
}
