//! A space-time occupancy grid: one [`OccupancyGrid`] per time bin, for fields that change with
//! time. A single grid over all times keeps every cell a mover ever crosses, so rays at one time
//! march through the whole swept volume; a bin's grid keeps only what is occupied during its
//! slice of time. A batch of rays at one time marches through its bin's grid, a batch of mixed
//! times through the union of the bins.

use rand::Rng;

use crate::occupancy::{OccupancyConfig, OccupancyGrid};

/// Densities at `[M, 3]` positions (host), each at its own time (M times).
pub type SpaceTimeDensity<'a> = dyn FnMut(&[f32], &[f32]) -> Vec<f32> + 'a;

#[derive(Clone, Debug, PartialEq)]
pub struct TimedOccupancy {
    /// Bin k covers times [t0 + k·w, t0 + (k+1)·w) with w = (t1 − t0) / bins.
    bins: Vec<OccupancyGrid>,
    /// Cells occupied in any bin; `None` with one bin (the bin is the union).
    union: Option<OccupancyGrid>,
    /// `[t0, t1]`: the times the bins split (times outside fall in the first or last bin).
    range: [f32; 2],
    /// The bin the next update refreshes.
    next: usize,
}

impl TimedOccupancy {
    /// `bins` grids (at least one), all starting fully occupied, splitting `range` evenly.
    /// The bins take turns to refresh, so each decays by `config.decay` to the power of the
    /// number of bins per own refresh: a cell that empties leaves the grid after as many
    /// training steps as with one grid (about 80 updates from 0.5 at 0.95; it would take
    /// `bins` times longer otherwise).
    pub fn new(config: OccupancyConfig, aabb: [[f32; 3]; 2], bins: usize, range: [f32; 2]) -> Self {
        let n = bins.max(1);
        let config = OccupancyConfig {
            decay: config.decay.powi(n as i32),
            ..config
        };
        let bins: Vec<OccupancyGrid> = (0..n).map(|_| OccupancyGrid::new(config.clone(), aabb)).collect();
        let union = (bins.len() > 1).then(|| OccupancyGrid::union_of(&bins)).flatten();
        TimedOccupancy {
            bins,
            union,
            range,
            next: 0,
        }
    }

    pub fn num_bins(&self) -> usize {
        self.bins.len()
    }

    /// The bin holding time `t` (clamped to the range; NaN falls in the first bin).
    pub fn bin_of(&self, t: f32) -> usize {
        let n = self.bins.len();
        let [t0, t1] = self.range;
        if n == 1 || t1 <= t0 {
            return 0;
        }
        let u = ((t - t0) / (t1 - t0) * n as f32).floor();
        if u.is_nan() {
            0
        } else {
            (u.max(0.0) as usize).min(n - 1)
        }
    }

    /// The times `[start, end)` of bin `k`.
    pub fn bin_range(&self, k: usize) -> [f32; 2] {
        let [t0, t1] = self.range;
        let w = (t1 - t0) / self.bins.len() as f32;
        [t0 + k as f32 * w, t0 + (k + 1) as f32 * w]
    }

    /// The grid rays at time `t` march through.
    pub fn at(&self, t: f32) -> &OccupancyGrid {
        &self.bins[self.bin_of(t)]
    }

    /// The grid rays of mixed times march through: cells occupied in any bin.
    pub fn union(&self) -> &OccupancyGrid {
        self.union.as_ref().unwrap_or(&self.bins[0])
    }

    pub fn bins(&self) -> &[OccupancyGrid] {
        &self.bins
    }

    /// Changes the bins' grids through `f` (loading a checkpoint, carving), then rebuilds the union.
    pub fn with_bins_mut<R>(&mut self, f: impl FnOnce(&mut [OccupancyGrid]) -> R) -> R {
        let out = f(&mut self.bins);
        self.rebuild_union();
        out
    }

    fn rebuild_union(&mut self) {
        if self.bins.len() > 1 {
            self.union = OccupancyGrid::union_of(&self.bins);
        }
    }

    /// Whether `step` is an update step.
    pub fn due(&self, step: usize) -> bool {
        self.bins[0].due(step)
    }

    /// Fraction of cells occupied in any bin.
    pub fn occupied_fraction(&self) -> f32 {
        self.union().occupied_fraction()
    }

    /// Mean over bins of their occupied fractions (what one time's rays see).
    pub fn mean_bin_fraction(&self) -> f32 {
        self.bins.iter().map(|g| g.occupied_fraction()).sum::<f32>() / self.bins.len() as f32
    }

    /// Refreshes one bin, the bins taking turns, so an update costs what one grid's does (each
    /// bin's values decay once per own refresh). `density(points, times)` maps `[M, 3]` world
    /// positions at M times to densities; `time_in(k)` draws a time in bin `k` for each point.
    pub fn update(
        &mut self,
        step: usize,
        step_size: f32,
        rng: &mut impl Rng,
        time_in: &mut dyn FnMut(usize) -> f32,
        density: &mut SpaceTimeDensity,
    ) {
        let k = self.next;
        self.next = (k + 1) % self.bins.len();
        let mut at_times = |p: &[f32]| -> Vec<f32> {
            let t: Vec<f32> = (0..p.len() / 3).map(|_| time_in(k)).collect();
            density(p, &t)
        };
        self.bins[k].update(step, step_size, rng, &mut at_times);
        self.rebuild_union();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{SeedableRng, rngs::StdRng};

    fn config() -> OccupancyConfig {
        OccupancyConfig {
            resolution: 16,
            warmup_steps: 1_000_000, // every update refreshes all of its bin's cells
            ..Default::default()
        }
    }

    /// A ball of radius 0.3 moving along x from −0.5 at t = 0 to +0.5 at t = 1.
    fn moving_ball(p: &[f32], t: &[f32]) -> Vec<f32> {
        p.chunks(3)
            .zip(t)
            .map(|(q, &t)| {
                let c = [-0.5 + t, 0.0, 0.0];
                let d2: f32 = (0..3).map(|a| (q[a] - c[a]).powi(2)).sum();
                if d2 < 0.09 { 100.0 } else { 0.0 }
            })
            .collect()
    }

    #[test]
    fn bins_split_the_range_and_clamp_outside_it() {
        let g = TimedOccupancy::new(config(), [[-1.0; 3], [1.0; 3]], 4, [0.0, 1.0]);
        assert_eq!(g.bin_of(0.0), 0);
        assert_eq!(g.bin_of(0.249), 0);
        assert_eq!(g.bin_of(0.25), 1);
        assert_eq!(g.bin_of(0.99), 3);
        assert_eq!(g.bin_of(1.0), 3);
        assert_eq!(g.bin_of(-3.0), 0);
        assert_eq!(g.bin_of(7.0), 3);
        assert_eq!(g.bin_of(f32::NAN), 0);
        assert_eq!(g.bin_range(2), [0.5, 0.75]);
        let one = TimedOccupancy::new(config(), [[-1.0; 3], [1.0; 3]], 1, [0.0, 1.0]);
        assert_eq!(one.bin_of(0.9), 0);
    }

    /// Each bin keeps where the ball is during its slice of time, and the union the whole
    /// swept volume: the start of the path is empty late, and every bin holds less than the union.
    #[test]
    fn each_bin_holds_the_mover_at_its_own_times() {
        let mut g = TimedOccupancy::new(config(), [[-1.0; 3], [1.0; 3]], 4, [0.0, 1.0]);
        let mut rng = StdRng::seed_from_u64(1);
        let mut trng = StdRng::seed_from_u64(2);
        for step in 0..4 {
            let mut time_in = |k: usize| {
                let [lo, hi] = [k as f32 * 0.25, (k + 1) as f32 * 0.25];
                lo + (hi - lo) * trng.random::<f32>()
            };
            g.update(step, 0.01, &mut rng, &mut time_in, &mut |p, t| moving_ball(p, t));
        }
        let start = [-0.5, 0.0, 0.0];
        let end = [0.5, 0.0, 0.0];
        assert!(g.at(0.05).is_occupied(start) && !g.at(0.05).is_occupied(end));
        assert!(g.at(0.95).is_occupied(end) && !g.at(0.95).is_occupied(start));
        assert!(g.union().is_occupied(start) && g.union().is_occupied(end));
        let union = g.occupied_fraction();
        for b in g.bins() {
            assert!(
                b.occupied_fraction() < 0.75 * union,
                "{} vs {union}",
                b.occupied_fraction()
            );
        }
        assert!(g.mean_bin_fraction() < union);
    }

    /// The bins take turns: one update changes one bin's grid only.
    #[test]
    fn an_update_refreshes_one_bin() {
        let mut g = TimedOccupancy::new(config(), [[-1.0; 3], [1.0; 3]], 3, [0.0, 1.0]);
        let mut rng = StdRng::seed_from_u64(0);
        g.update(0, 0.01, &mut rng, &mut |_| 0.5, &mut |p, t| moving_ball(p, t));
        assert!(g.bins()[0].occupied_fraction() < 1.0);
        assert_eq!(g.bins()[1].occupied_fraction(), 1.0);
        assert_eq!(g.bins()[2].occupied_fraction(), 1.0);
        assert_eq!(g.occupied_fraction(), 1.0, "the union still holds the fresh bins");
    }
}
