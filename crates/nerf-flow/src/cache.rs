//! Flow cache in NSFF's `flow_i1/` layout (method.md §4.1): `{i:05}_fwd.npz` for frames
//! 0..N−2 and `{i:05}_bwd.npz` for frames 1..N−1, each with `flow` (H×W×2 float32, pixels) and
//! `mask` (H×W float32, 0/1). NSFF's own loader and [`nerf_data::video::load`] read these files.
//! Beside them, `key.txt` holds [`cache_key`]: what the flows were computed from. A cache whose
//! key differs (another video in the same run folder, other settings, no key) is not read.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use nerf_data::Image;
use nerf_data::dataset::FlowField;
use nerf_data::error::{DataError, Result};

use crate::FlowParams;

type Flows = (Vec<Option<FlowField>>, Vec<Option<FlowField>>);

const KEY_FILE: &str = "key.txt";

/// What a cache of the flows of `frames` (in time order) computed with `params` is keyed by:
/// the frame count and size, a 64-bit FNV-1a hash of every frame's pixels, and the settings.
/// Two videos of the same size differ in their hash, so a run folder reused for another video
/// recomputes its flows instead of reading the old ones.
pub fn cache_key(frames: &[&Image], params: &FlowParams) -> String {
    let mut hash = Fnv::new();
    for image in frames {
        hash.write(&image.width.to_le_bytes());
        hash.write(&image.height.to_le_bytes());
        hash.write(&image.channels.to_le_bytes());
        for v in &image.data {
            hash.write(&v.to_bits().to_le_bytes());
        }
    }
    let size = frames.first().map_or((0, 0), |i| (i.width, i.height));
    format!(
        "frames {} size {}x{} pixels {:016x}\nflow {params:?}\n",
        frames.len(),
        size.0,
        size.1,
        hash.0
    )
}

/// 64-bit FNV-1a: a stable, dependency-free fingerprint (not a cryptographic one).
struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

fn flow_path(dir: &Path, i: usize, direction: &str) -> PathBuf {
    dir.join(format!("{i:05}_{direction}.npz"))
}

/// Writes every present field of `fwd` and `bwd` (indexed by frame) into `dir` (created if
/// needed), then `key` ([`cache_key`]). Each file is written atomically and the key goes last
/// (an older one is removed first), so an interrupted run leaves a cache that
/// [`read_flow_cache`] does not read rather than a mixed one.
pub fn write_flow_cache(
    dir: &Path,
    key: &str,
    fwd: &[Option<FlowField>],
    bwd: &[Option<FlowField>],
) -> Result<()> {
    let key_path = dir.join(KEY_FILE);
    match std::fs::remove_file(&key_path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(DataError::io(&key_path, e)),
        _ => {}
    }
    let jobs: Vec<(PathBuf, &FlowField)> = [(fwd, "fwd"), (bwd, "bwd")]
        .into_iter()
        .flat_map(|(fields, direction)| {
            fields
                .iter()
                .enumerate()
                .filter_map(move |(i, f)| f.as_ref().map(|f| (flow_path(dir, i, direction), f)))
        })
        .collect();
    jobs.par_iter()
        .try_for_each(|(path, field)| write_field(path, field))?;
    nerf_data::image::write_atomic(&key_path, key.as_bytes())
}

fn write_field(path: &Path, field: &FlowField) -> Result<()> {
    let (w, h) = (field.width as usize, field.height as usize);
    if field.flow.len() != 2 * w * h || field.mask.len() != w * h {
        return Err(DataError::invalid(
            path,
            format!(
                "cannot write a {w}x{h} flow field with {} flow and {} mask values",
                field.flow.len(),
                field.mask.len()
            ),
        ));
    }
    let wide = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
    let flow = nerf_data::npy::encode_npy(&[h, w, 2], &wide(&field.flow), true);
    let mask = nerf_data::npy::encode_npy(&[h, w], &wide(&field.mask), true);
    // Deflated like numpy.savez_compressed: the masks shrink to almost nothing.
    let zip = nerf_data::npz::write_zip(&[("flow.npy", &flow), ("mask.npy", &mask)], true);
    nerf_data::image::write_atomic(path, &zip)
}

/// Reads the cache for `n_frames` frames of `width` x `height` computed as `key` says
/// ([`cache_key`]). `Ok(None)` when `dir`, its key or any of the expected files is missing, or
/// the key differs (compute the flows, then write the cache). A file of a cache whose key matches
/// but that is unreadable or has the wrong shape is an error naming it: the folder was damaged.
pub fn read_flow_cache(
    dir: &Path,
    key: &str,
    n_frames: usize,
    width: u32,
    height: u32,
) -> Result<Option<Flows>> {
    if !dir.is_dir() {
        return Ok(None);
    }
    let key_path = dir.join(KEY_FILE);
    match std::fs::read(&key_path) {
        Ok(stored) if stored == key.as_bytes() => {}
        Ok(_) => return Ok(None),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(DataError::io(&key_path, e)),
    }
    let wanted: Vec<(usize, &str)> = (0..n_frames)
        .flat_map(|i| [(i, "fwd"), (i, "bwd")])
        .filter(|&(i, d)| if d == "fwd" { i + 1 < n_frames } else { i > 0 })
        .collect();
    if wanted.iter().any(|&(i, d)| !flow_path(dir, i, d).is_file()) {
        return Ok(None);
    }
    let (w, h) = (width as usize, height as usize);
    let read = |fwd: bool| -> Result<Vec<Option<FlowField>>> {
        (0..n_frames)
            .into_par_iter()
            .map(|i| {
                let present = if fwd { i + 1 < n_frames } else { i > 0 };
                present
                    .then(|| {
                        nerf_data::video::read_flow(&flow_path(dir, i, if fwd { "fwd" } else { "bwd" }), w, h)
                    })
                    .transpose()
            })
            .collect()
    };
    let (fwd, bwd) = rayon::join(|| read(true), || read(false));
    Ok(Some((fwd?, bwd?)))
}
