//! Multiresolution hash encoding (Instant-NGP) as a fused CPU op with a hand-written backward
//! and a sparse (touched-rows-only) Adam update.
//!
//! Per level l the grid has resolution N_l = ⌊N_min·b^l⌋ with b = exp((ln N_max − ln N_min)/(L−1)).
//! A point x ∈ [0, 1]^D is scaled by N_l; its 2^D integer corners index the level's table, densely
//! (row-major) when (N_l + 1)^D entries fit in the table, otherwise through the spatial hash
//! h(v) = (⊕_i v_i·π_i) mod T with π = (1, 2654435761, 805459861, 3674653429) in wrapping u32
//! arithmetic. The F features of the corners are blended with D-linear weights Π_i(1 − |x_i N_l − v_i|).
//!
//! The table lives on the host, not in burn: burn's dense gradient and Adam would touch all
//! L·T·F entries every step (about 200 ms for 16 × 2^19 × 2 here), while a batch touches a small
//! fraction. The op's backward accumulates table gradients into a host buffer and records which
//! entries it touched; [`HashGrid::adam_step`] updates only those. The burn graph reaches the
//! backward through a one-element "anchor" input that requires grad.

use std::sync::{Arc, Mutex, RwLock};

use burn::tensor::{Device, Int, Tensor, TensorData};
use rand::{Rng, SeedableRng, rngs::StdRng};
use rayon::prelude::*;

use crate::host_op::{HostKernel, HostTensor, host_op};
use crate::optim::{AdamParams, SparseAdam};

/// Spatial-hash primes (the first is 1 on purpose, for memory coherence along x).
pub const PRIMES: [u32; 4] = [1, 2_654_435_761, 805_459_861, 3_674_653_429];

/// Hash grid hyper-parameters.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HashGridConfig {
    /// Input dimension: 3 for space, 4 for space-time.
    pub dims: usize,
    pub levels: usize,
    pub features: usize,
    /// log2 of the maximum entries per level (T).
    pub log2_table: u32,
    pub base_resolution: u32,
    pub finest_resolution: u32,
    /// For space-time grids: cap on the resolution of the last input dimension, so coarse and
    /// fine levels alike stop subdividing time between video frames (e.g. frames − 1).
    #[serde(default)]
    pub time_resolution: Option<u32>,
    /// With `time_resolution`: each level's time resolution follows its spatial resolution
    /// (`time_resolution · resolution / finest_resolution`, at least 1), so coarse levels share
    /// their features across many frames and only the finest levels resolve single frames.
    #[serde(default)]
    pub time_follows_space: bool,
}

impl Default for HashGridConfig {
    fn default() -> Self {
        HashGridConfig {
            dims: 3,
            levels: 16,
            features: 2,
            log2_table: 19,
            base_resolution: 16,
            finest_resolution: 2048,
            time_resolution: None,
            time_follows_space: false,
        }
    }
}

impl HashGridConfig {
    pub fn output_dim(&self) -> usize {
        self.levels * self.features
    }

    /// The per-level growth factor b.
    pub fn growth(&self) -> f64 {
        if self.levels <= 1 {
            return 1.0;
        }
        ((self.finest_resolution as f64).ln() - (self.base_resolution as f64).ln()) / (self.levels - 1) as f64
    }
}

/// Geometry of one level.
#[derive(Clone, Debug, PartialEq)]
pub struct Level {
    /// N_l: positions are scaled by this.
    pub resolution: u32,
    /// Per input dimension: N_l, except a capped time resolution for space-time grids.
    pub resolutions: [u32; 4],
    /// First entry of this level in the flat table.
    pub offset: usize,
    /// Entries in this level (≤ T).
    pub size: usize,
    /// Dense (collision-free) indexing.
    pub dense: bool,
}

/// Level layout for a config.
pub fn levels(cfg: &HashGridConfig) -> Vec<Level> {
    let t_max = 1usize << cfg.log2_table;
    let b = cfg.growth().exp();
    let mut offset = 0;
    (0..cfg.levels)
        .map(|l| {
            let resolution = (cfg.base_resolution as f64 * b.powi(l as i32)).floor() as u32;
            let mut resolutions = [resolution; 4];
            if let (Some(cap), true) = (cfg.time_resolution, cfg.dims >= 2) {
                let cap = cap.max(1);
                resolutions[cfg.dims - 1] = if cfg.time_follows_space {
                    let scaled = cap as f64 * resolution as f64 / cfg.finest_resolution.max(1) as f64;
                    (scaled.round() as u32).clamp(1, cap)
                } else {
                    resolution.min(cap)
                };
            }
            let dense_size = resolutions[..cfg.dims]
                .iter()
                .try_fold(1usize, |acc, r| acc.checked_mul(*r as usize + 1))
                .unwrap_or(usize::MAX);
            let (size, dense) = if dense_size <= t_max {
                (dense_size.div_ceil(8) * 8, true)
            } else {
                (t_max, false)
            };
            let level = Level {
                resolution,
                resolutions,
                offset,
                size,
                dense,
            };
            offset += size;
            level
        })
        .collect()
}

/// Table index of integer corner `v` at `level`.
#[inline(always)]
pub fn corner_index(level: &Level, v: &[u32]) -> usize {
    if level.dense {
        let mut idx = 0usize;
        for (d, &c) in v.iter().enumerate().rev() {
            idx = idx * (level.resolutions[d] as usize + 1) + c as usize;
        }
        idx
    } else {
        let mut h = 0u32;
        for (c, p) in v.iter().zip(PRIMES) {
            h ^= c.wrapping_mul(p);
        }
        (h as usize) & (level.size - 1)
    }
}

/// The 2^D (= C) corners of the cell holding `x` at one level: flat table indices (level offset
/// included) and D-linear weights. Returns the in-cell position (for the position gradient).
/// `DENSE` is a compile-time copy of `level.dense` so the inner loops carry no branch.
#[inline(always)]
fn corners<const D: usize, const C: usize, const DENSE: bool>(
    level: &Level,
    x: &[f32],
    idx: &mut [u32; C],
    w: &mut [f32; C],
) -> [f32; D] {
    let mut lo_hi = [[0u32; 2]; D];
    let mut wt = [[0f32; 2]; D];
    let mut frac = [0f32; D];
    let mut stride = 1u32;
    for i in 0..D {
        let res = level.resolutions[i];
        let p = x[i].clamp(0.0, 1.0) * res as f32;
        // p ≥ 0, so truncation is floor (f32::floor is a libm call on baseline x86_64). The far
        // face x = 1 belongs to the last cell so that corner + 1 stays on the grid. NaN → 0.
        let v = (p as u32).min(res.saturating_sub(1));
        frac[i] = p - v as f32;
        wt[i] = [1.0 - frac[i], frac[i]];
        lo_hi[i] = if DENSE {
            [v * stride, (v + 1) * stride]
        } else {
            [v.wrapping_mul(PRIMES[i]), (v + 1).wrapping_mul(PRIMES[i])]
        };
        stride *= res + 1;
    }
    let mask = (level.size - 1) as u32;
    for c in 0..C {
        let mut h = 0u32;
        let mut weight = 1.0f32;
        for i in 0..D {
            let up = (c >> i) & 1;
            h = if DENSE { h + lo_hi[i][up] } else { h ^ lo_hi[i][up] };
            weight *= wt[i][up];
        }
        idx[c] = level.offset as u32 + if DENSE { h } else { h & mask };
        w[c] = weight;
    }
    frac
}

/// Hints the CPU to start loading `data[i]`; random table lookups are latency-bound, so issuing
/// the loads of the next block of points while using the current one hides most of it.
#[inline(always)]
fn prefetch(data: *const f32, i: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let ptr = data.wrapping_add(i) as *const i8;
        // SAFETY: prefetching never faults, even for an invalid address; sse is baseline on x86_64.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(ptr) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (data, i);
}

/// Points per block in the prefetch pipeline.
const BLOCK: usize = 32;

/// Streams every point of `pos` through one level: computes the corners a block ahead,
/// prefetching the rows they touch in each buffer of `data` (a buffer's row 0 is table entry
/// `base`, rows are `f_n` wide; raw pointers because `consume` may be writing a buffer), and
/// hands each point's corners and in-cell position to `consume(point, idx, w, frac)` (the
/// position only with `FRAC`; zeros otherwise, sparing the forward pass the stores).
#[inline(always)]
fn sweep_level<const D: usize, const C: usize, const DENSE: bool, const FRAC: bool>(
    level: &Level,
    pos: &[f32],
    data: &[(*const f32, usize)],
    f_n: usize,
    mut consume: impl FnMut(usize, &[u32; C], &[f32; C], &[f32; D]),
) {
    let n = pos.len() / D;
    let mut idx = [[[0u32; C]; BLOCK]; 2];
    let mut w = [[[0f32; C]; BLOCK]; 2];
    let mut frac = [[[0f32; D]; BLOCK]; 2];
    let fill = |start: usize,
                idx: &mut [[u32; C]; BLOCK],
                w: &mut [[f32; C]; BLOCK],
                frac: &mut [[f32; D]; BLOCK]| {
        for p in start..(start + BLOCK).min(n) {
            let j = p - start;
            let f = corners::<D, C, DENSE>(level, &pos[p * D..(p + 1) * D], &mut idx[j], &mut w[j]);
            if FRAC {
                frac[j] = f;
            }
            for &i in idx[j].iter() {
                for &(buf, base) in data {
                    prefetch(buf, (i as usize - base) * f_n);
                }
            }
        }
    };
    fill(0, &mut idx[0], &mut w[0], &mut frac[0]);
    for (b, start) in (0..n).step_by(BLOCK).enumerate() {
        let (idx_cur, idx_next) = split_pair(&mut idx, b % 2);
        let (w_cur, w_next) = split_pair(&mut w, b % 2);
        let (frac_cur, frac_next) = split_pair(&mut frac, b % 2);
        fill(start + BLOCK, idx_next, w_next, frac_next);
        for p in start..(start + BLOCK).min(n) {
            let j = p - start;
            consume(p, &idx_cur[j], &w_cur[j], &frac_cur[j]);
        }
    }
}

/// The `cur` element of a pair and the other one, both mutable.
fn split_pair<T>(pair: &mut [T; 2], cur: usize) -> (&mut T, &mut T) {
    let [a, b] = pair;
    if cur == 0 { (a, b) } else { (b, a) }
}

/// Calls `sweep_level` with `DENSE` matching the level.
#[inline(always)]
fn sweep<const D: usize, const C: usize, const FRAC: bool>(
    level: &Level,
    pos: &[f32],
    data: &[(*const f32, usize)],
    f_n: usize,
    consume: impl FnMut(usize, &[u32; C], &[f32; C], &[f32; D]),
) {
    if level.dense {
        sweep_level::<D, C, true, FRAC>(level, pos, data, f_n, consume)
    } else {
        sweep_level::<D, C, false, FRAC>(level, pos, data, f_n, consume)
    }
}

/// Entries per dirty-flag block: levels hold a multiple of 8 entries, so blocks never straddle
/// two levels and each level's flags can be written by its own thread.
const BLOCK_ENTRIES: usize = 8;

/// Accumulated table gradient and which blocks of entries it touched.
#[derive(Debug)]
struct GradBuffer {
    grad: Vec<f32>,
    dirty: Vec<bool>,
}

/// A hash grid: configuration, host table, gradient buffer and its optimiser.
#[derive(Debug)]
pub struct HashGrid {
    pub config: HashGridConfig,
    pub levels: Vec<Level>,
    /// `[entries, F]`, level after level.
    table: RwLock<Vec<f32>>,
    /// dL/dtable accumulated by backward passes until the next optimiser step.
    grads: Mutex<GradBuffer>,
    adam: Mutex<SparseAdam>,
}

impl HashGrid {
    /// A grid with entries drawn uniformly from [−1e-4, 1e-4].
    pub fn new(config: HashGridConfig, seed: u64) -> Arc<Self> {
        assert!(
            (1..=4).contains(&config.dims),
            "hash grid supports 1 to 4 dimensions"
        );
        let levels = levels(&config);
        let entries = levels.last().map_or(0, |l| l.offset + l.size);
        let mut rng = StdRng::seed_from_u64(seed);
        let table: Vec<f32> = (0..entries * config.features)
            .map(|_| rng.random_range(-1e-4..1e-4))
            .collect();
        Self::with_table(config, table)
    }

    /// A grid with the given table (`entries · F` values), e.g. from a checkpoint.
    pub fn with_table(config: HashGridConfig, table: Vec<f32>) -> Arc<Self> {
        let levels = levels(&config);
        let entries = levels.last().map_or(0, |l| l.offset + l.size);
        assert_eq!(
            table.len(),
            entries * config.features,
            "table size for {config:?}"
        );
        let grads = GradBuffer {
            grad: vec![0.0; table.len()],
            dirty: vec![false; entries.div_ceil(BLOCK_ENTRIES)],
        };
        let adam = SparseAdam::new(table.len());
        Arc::new(HashGrid {
            config,
            levels,
            table: RwLock::new(table),
            grads: Mutex::new(grads),
            adam: Mutex::new(adam),
        })
    }

    pub fn num_entries(&self) -> usize {
        self.levels.last().map_or(0, |l| l.offset + l.size)
    }

    pub fn num_params(&self) -> usize {
        self.num_entries() * self.config.features
    }

    /// Replaces the table (checkpoint loading); `Err` with the expected size when it does not fit.
    pub fn set_table(&self, table: Vec<f32>) -> Result<(), usize> {
        if table.len() != self.num_params() {
            return Err(self.num_params());
        }
        *self.table.write().unwrap_or_else(|e| e.into_inner()) = table;
        Ok(())
    }

    /// Fills the table with a fixed pseudo-random pattern in [−0.5, 0.5). A fresh grid's
    /// features are near zero, so its field hardly varies from point to point; tests that must
    /// tell one sample from another spread the tables first.
    pub fn spread(&self) {
        let n = self.num_params();
        *self.table.write().unwrap_or_else(|e| e.into_inner()) = (0..n)
            .map(|i| ((i * 7919 % 1009) as f32 / 1009.0) - 0.5)
            .collect();
    }

    /// A copy of the table.
    pub fn table(&self) -> Vec<f32> {
        self.table.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Encodes `[N, D]` positions in [0, 1]^D into `[N, L·F]` features. Differentiable: the table
    /// gradient lands in this grid's buffer, the position gradient flows on in the graph.
    pub fn encode(self: &Arc<Self>, positions: Tensor<2>) -> Tensor<2> {
        let device = positions.device();
        let anchor = Tensor::<2>::zeros([1, 1], &device);
        let anchor = if device.is_autodiff() {
            anchor.require_grad()
        } else {
            anchor
        };
        host_op(
            vec![positions, anchor],
            Arc::new(HashEncodeKernel { grid: self.clone() }),
        )
    }

    /// Host-side encoding (no graph): `[N, D]` → `[N, L·F]`.
    pub fn encode_host(&self, positions: &[f32]) -> Vec<f32> {
        let table = self.table.read().unwrap_or_else(|e| e.into_inner());
        match self.config.dims {
            1 => self.forward::<1, 2>(&table, positions),
            2 => self.forward::<2, 4>(&table, positions),
            3 => self.forward::<3, 8>(&table, positions),
            _ => self.forward::<4, 16>(&table, positions),
        }
    }

    fn forward<const D: usize, const C: usize>(&self, table: &[f32], positions: &[f32]) -> Vec<f32> {
        let f_n = self.config.features;
        let levels = self.levels.len();
        let width = levels * f_n;
        let n = positions.len() / D;
        // Level-major: one task streams all points through one level, so its random reads stay
        // within that level's table (a few MB: cache-resident) instead of all of them.
        let mut by_level = vec![0.0f32; n * width];
        by_level
            .par_chunks_mut(n * f_n)
            .zip(&self.levels)
            .for_each(|(dst, level)| {
                sweep::<D, C, false>(level, positions, &[(table.as_ptr(), 0)], f_n, |p, idx, w, _| {
                    let o = &mut dst[p * f_n..(p + 1) * f_n];
                    if f_n == 2 {
                        // The common case, unrolled into registers.
                        let (mut a, mut b) = (0.0f32, 0.0f32);
                        for k in 0..C {
                            let i = idx[k] as usize * 2;
                            a += w[k] * table[i];
                            b += w[k] * table[i + 1];
                        }
                        o[0] = a;
                        o[1] = b;
                    } else {
                        for k in 0..C {
                            let i = idx[k] as usize * f_n;
                            for f in 0..f_n {
                                o[f] += w[k] * table[i + f];
                            }
                        }
                    }
                });
            });
        // Interleave the levels per point, parallel over output rows.
        let mut out = vec![0.0f32; n * width];
        out.par_chunks_mut(width * 1024)
            .enumerate()
            .for_each(|(chunk, rows)| {
                for (i, row) in rows.chunks_exact_mut(width).enumerate() {
                    let p = chunk * 1024 + i;
                    for l in 0..levels {
                        let src = (l * n + p) * f_n;
                        row[l * f_n..(l + 1) * f_n].copy_from_slice(&by_level[src..src + f_n]);
                    }
                }
            });
        out
    }

    /// Accumulates dL/dtable from dL/dfeatures `[N, L·F]` into the gradient buffer and, with
    /// `want_positions`, returns dL/dpositions `[N, D]` as well. One level-major pass (parallel
    /// over levels: no races) computes each point's corners once for both gradients; a task's
    /// random table reads and writes stay within its level's rows (a few MB: cache-resident;
    /// point-major reads of every level missed the cache: 8x slower on a 4-D grid).
    fn backward_host<const D: usize, const C: usize>(
        &self,
        positions: &[f32],
        grad_out: &[f32],
        want_positions: bool,
    ) -> Option<Vec<f32>> {
        let f_n = self.config.features;
        let width = self.levels.len() * f_n;
        let n = positions.len() / D;
        let mut buf = self.grads.lock().unwrap_or_else(|e| e.into_inner());
        let GradBuffer { grad, dirty } = &mut *buf;
        // The position gradient reads the table. Locked after the gradient buffer, the order
        // `adam_step` takes them in.
        let table = want_positions.then(|| self.table.read().unwrap_or_else(|e| e.into_inner()));
        let table = table.as_deref().map(Vec::as_slice);
        // Split the gradient buffer and the dirty flags by level (levels are contiguous), and
        // give each level its own rows of the position gradient (summed over levels below).
        let mut by_level = vec![
            0.0f32;
            if table.is_some() {
                self.levels.len() * n * D
            } else {
                0
            }
        ];
        let mut dpos_parts = by_level.chunks_mut((n * D).max(1));
        let mut parts = Vec::new();
        let (mut rest, mut rest_dirty) = (grad.as_mut_slice(), dirty.as_mut_slice());
        for level in &self.levels {
            let (a, b) = std::mem::take(&mut rest).split_at_mut(level.size * f_n);
            let (da, db) = std::mem::take(&mut rest_dirty).split_at_mut(level.size / BLOCK_ENTRIES);
            parts.push((a, da, dpos_parts.next()));
            rest = b;
            rest_dirty = db;
        }
        // Each level reads its own columns of the upstream gradient: a strided stream the
        // hardware prefetcher follows, cheaper than transposing the whole matrix first.
        parts
            .into_par_iter()
            .enumerate()
            .zip(&self.levels)
            .for_each(|((l, (g, dirty, mut dpos)), level)| {
                let offset = level.offset;
                let res: [f32; D] = std::array::from_fn(|a| level.resolutions[a] as f32);
                let prefetch = [
                    (g.as_ptr(), offset),
                    (table.map_or(g.as_ptr(), <[f32]>::as_ptr), 0),
                ];
                let mut consume = |p: usize, idx: &[u32; C], w: &[f32; C], frac: &[f32; D]| {
                    let up = &grad_out[p * width + l * f_n..p * width + (l + 1) * f_n];
                    for k in 0..C {
                        let e = idx[k] as usize - offset;
                        dirty[e / BLOCK_ENTRIES] = true;
                        let i = e * f_n;
                        if f_n == 2 {
                            g[i] += w[k] * up[0];
                            g[i + 1] += w[k] * up[1];
                        } else {
                            for f in 0..f_n {
                                g[i + f] += w[k] * up[f];
                            }
                        }
                    }
                    let (Some(table), Some(dpos)) = (table, dpos.as_deref_mut()) else {
                        return;
                    };
                    let x = &positions[p * D..(p + 1) * D];
                    let dx = &mut dpos[p * D..(p + 1) * D];
                    let mut dot = [0f32; C];
                    for (d, &i) in dot.iter_mut().zip(idx) {
                        let row = &table[i as usize * f_n..(i as usize + 1) * f_n];
                        *d = row.iter().zip(up).map(|(t, u)| t * u).sum();
                    }
                    for a in 0..D {
                        if !(0.0..=1.0).contains(&x[a]) {
                            continue; // clamped coordinate: no gradient
                        }
                        // Corners c and c + 2^a differ in axis a only: the D-linear weight's
                        // derivative along a is the product of the other axes' weights, with a
                        // sign.
                        let mut acc = 0.0f32;
                        for c in (0..C).filter(|c| (c >> a) & 1 == 0) {
                            let mut w = 1.0f32;
                            for i in (0..D).filter(|&i| i != a) {
                                w *= if (c >> i) & 1 == 1 { frac[i] } else { 1.0 - frac[i] };
                            }
                            acc += w * (dot[c | (1 << a)] - dot[c]);
                        }
                        dx[a] += res[a] * acc;
                    }
                };
                if table.is_some() {
                    sweep::<D, C, true>(level, positions, &prefetch, f_n, &mut consume);
                } else {
                    sweep::<D, C, false>(level, positions, &prefetch[..1], f_n, &mut consume);
                }
            });
        table?;
        // Sum the levels per coordinate, parallel over rows.
        let mut out = vec![0.0f32; n * D];
        out.par_chunks_mut(D * 1024)
            .enumerate()
            .for_each(|(chunk, rows)| {
                for (i, v) in rows.iter_mut().enumerate() {
                    let j = chunk * D * 1024 + i;
                    *v = (0..self.levels.len()).map(|l| by_level[l * n * D + j]).sum();
                }
            });
        Some(out)
    }

    /// Clears accumulated gradients (when a step is skipped).
    pub fn zero_grad(&self) {
        let mut buf = self.grads.lock().unwrap_or_else(|e| e.into_inner());
        buf.grad.par_chunks_mut(1 << 16).for_each(|c| c.fill(0.0));
        buf.dirty.fill(false);
    }

    /// Number of table entries with a non-zero gradient since the last step.
    pub fn touched(&self) -> usize {
        let buf = self.grads.lock().unwrap_or_else(|e| e.into_inner());
        buf.grad
            .chunks(self.config.features)
            .filter(|r| r.iter().any(|v| *v != 0.0))
            .count()
    }

    /// Dense copy of the accumulated table gradient (tests and diagnostics).
    pub fn grad(&self) -> Vec<f32> {
        self.grads.lock().unwrap_or_else(|e| e.into_inner()).grad.clone()
    }

    /// Adam on the entries with a gradient only, then clears the gradients. Entries untouched
    /// this step keep their value and their moments (Instant-NGP skips zero-gradient entries too).
    /// Returns the number of entries updated.
    pub fn adam_step(&self, params: &AdamParams, lr: f64) -> usize {
        let mut buf = self.grads.lock().unwrap_or_else(|e| e.into_inner());
        let GradBuffer { grad, dirty } = &mut *buf;
        let mut table = self.table.write().unwrap_or_else(|e| e.into_inner());
        let mut adam = self.adam.lock().unwrap_or_else(|e| e.into_inner());
        adam.step(
            params,
            lr,
            &mut table,
            grad,
            self.config.features,
            dirty,
            BLOCK_ENTRIES,
        )
    }

    /// Optimiser state for checkpoints: (step, first moments, second moments).
    pub fn adam_state(&self) -> (u64, Vec<f32>, Vec<f32>) {
        self.adam.lock().unwrap_or_else(|e| e.into_inner()).state()
    }

    pub fn set_adam_state(&self, step: u64, m: Vec<f32>, v: Vec<f32>) {
        self.adam
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .set_state(step, m, v);
    }
}

/// The fused op: inputs positions `[N, D]` and the anchor `[1, 1]`; output `[N, L·F]`.
#[derive(Debug)]
struct HashEncodeKernel {
    grid: Arc<HashGrid>,
}

impl HostKernel for HashEncodeKernel {
    fn forward(&self, inputs: &[HostTensor]) -> HostTensor {
        let n = inputs[0].shape[0];
        let out = self.grid.encode_host(&inputs[0].data);
        HostTensor::new(vec![n, self.grid.config.output_dim()], out)
    }

    fn backward(
        &self,
        inputs: &[HostTensor],
        _: &HostTensor,
        grad: &HostTensor,
        wanted: &[bool],
    ) -> Vec<Option<HostTensor>> {
        let pos = &inputs[0].data;
        let g = &self.grid;

        let want = wanted[0];
        let name = if want {
            "bwd.hash_table_position"
        } else {
            "bwd.hash_table"
        };
        let dpos = crate::profile::span(name, || match g.config.dims {
            1 => g.backward_host::<1, 2>(pos, &grad.data, want),
            2 => g.backward_host::<2, 4>(pos, &grad.data, want),
            3 => g.backward_host::<3, 8>(pos, &grad.data, want),
            _ => g.backward_host::<4, 16>(pos, &grad.data, want),
        })
        .map(|d| HostTensor::new(inputs[0].shape.clone(), d));
        vec![dpos, None]
    }
}

/// The same encoding written with generic burn tensor ops (floor, integer hash, `select`,
/// weighted sum), with the table as an ordinary tensor: the baseline the fused op is measured
/// against, and an independent cross-check of its values and gradients. 3-D only.
///
/// `table`: `[entries, F]`; `positions`: `[N, 3]` in [0, 1]; returns `[N, L·F]`.
pub fn encode_reference(cfg: &HashGridConfig, table: Tensor<2>, positions: Tensor<2>) -> Tensor<2> {
    assert_eq!(cfg.dims, 3);
    let device: Device = positions.device();
    let n = positions.dims()[0];
    let mut outs = Vec::new();
    for level in levels(cfg) {
        let res = level.resolution as f32;
        let p = positions.clone().clamp(0.0, 1.0) * res;
        let base = p.clone().floor().clamp(0.0, res - 1.0);
        let frac = p - base.clone();
        let base_i: Tensor<2, Int> = base.int();
        let mut acc: Option<Tensor<2>> = None;
        for corner in 0..8usize {
            let mut idx: Option<Tensor<1, Int>> = None;
            let mut w: Option<Tensor<1>> = None;
            for a in 0..3 {
                let up = (corner >> a) & 1;
                let v = base_i.clone().slice([0..n, a..a + 1]).reshape([n]) + up as i64;
                let fa = frac.clone().slice([0..n, a..a + 1]).reshape([n]);
                let wa = if up == 1 { fa } else { fa.neg().add_scalar(1.0) };
                w = Some(match w {
                    None => wa,
                    Some(w) => w * wa,
                });
                let term = if level.dense {
                    v * ((level.resolution as i64 + 1).pow(a as u32))
                } else {
                    v * (PRIMES[a] as i32 as i64)
                };
                idx = Some(match idx {
                    None => term,
                    Some(i) if level.dense => i + term,
                    Some(i) => i.bitwise_xor(term),
                });
            }
            let mut idx = idx.unwrap_or_else(|| Tensor::zeros([n], &device));
            if !level.dense {
                idx = idx.bitwise_and_scalar(level.size as i64 - 1);
            }
            let rows = table.clone().select(0, idx + level.offset as i64);
            let contrib = rows
                * w.unwrap_or_else(|| Tensor::ones([n], &device))
                    .unsqueeze_dim::<2>(1);
            acc = Some(match acc {
                None => contrib,
                Some(a) => a + contrib,
            });
        }
        outs.extend(acc);
    }
    Tensor::cat(outs, 1)
}

/// Table as a burn tensor (for the reference path and diagnostics).
pub fn table_tensor(grid: &HashGrid, device: &Device) -> Tensor<2> {
    let f = grid.config.features;
    Tensor::from_data(TensorData::new(grid.table(), [grid.num_entries(), f]), device)
}
