//! Shared by the encoding tests: the hash-grid encoding in f64, written from the definition.

use nerf_core::encoding::hash_grid::{HashGridConfig, levels};

/// f64 definition for any dimension and per-dimension resolutions (space-time grids).
pub fn encode_f64_nd(cfg: &HashGridConfig, table: &[f32], x: &[f64]) -> Vec<f64> {
    let d = cfg.dims;
    let primes: [u64; 4] = [1, 2_654_435_761, 805_459_861, 3_674_653_429];
    let mut out = Vec::new();
    for level in levels(cfg) {
        let mut feats = vec![0.0; cfg.features];
        for corner in 0..(1usize << d) {
            let (mut w, mut dense_idx, mut stride, mut h) = (1.0, 0u64, 1u64, 0u32);
            for a in 0..d {
                let res = level.resolutions[a] as f64;
                let p = x[a].clamp(0.0, 1.0) * res;
                let base = p.floor().min(res - 1.0);
                let up = (corner >> a) & 1;
                let v = base as u64 + up as u64;
                w *= if up == 1 { p - base } else { 1.0 - (p - base) };
                dense_idx += v * stride;
                stride *= level.resolutions[a] as u64 + 1;
                h ^= (v * primes[a]) as u32;
            }
            let idx = if level.dense {
                dense_idx
            } else {
                h as u64 % level.size as u64
            };
            for f in 0..cfg.features {
                feats[f] += w * table[(level.offset + idx as usize) * cfg.features + f] as f64;
            }
        }
        out.extend(feats);
    }
    out
}
