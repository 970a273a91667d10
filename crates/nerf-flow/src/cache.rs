//! Flow cache in NSFF's `flow_i1/` layout (method.md §4.1): `{i:05}_fwd.npz` for frames
//! 0..N−2 and `{i:05}_bwd.npz` for frames 1..N−1, each with `flow` (H×W×2 float32, pixels) and
//! `mask` (H×W float32, 0/1). NSFF's own loader and [`nerf_data::video::load`] read these files.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use nerf_data::dataset::FlowField;
use nerf_data::error::{DataError, Result};

type Flows = (Vec<Option<FlowField>>, Vec<Option<FlowField>>);

fn flow_path(dir: &Path, i: usize, direction: &str) -> PathBuf {
    dir.join(format!("{i:05}_{direction}.npz"))
}

/// Writes every present field of `fwd` and `bwd` (indexed by frame) into `dir` (created if
/// needed). Each file is written atomically, so an interrupted run leaves whole files only and
/// [`read_flow_cache`] sees an incomplete cache rather than a corrupt one.
pub fn write_flow_cache(dir: &Path, fwd: &[Option<FlowField>], bwd: &[Option<FlowField>]) -> Result<()> {
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
        .try_for_each(|(path, field)| write_field(path, field))
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

/// Reads the cache for `n_frames` frames of `width` x `height`. `Ok(None)` when `dir` or any of
/// the expected files is missing (compute the flows, then write the cache). A file that exists
/// but is unreadable or has the wrong shape is an error naming it (e.g. a cache left over from
/// another resolution), since silently recomputing would hide a mixed-up folder.
///
/// The cache does not record which images it came from; key `dir` by the video and resolution.
pub fn read_flow_cache(dir: &Path, n_frames: usize, width: u32, height: u32) -> Result<Option<Flows>> {
    if !dir.is_dir() {
        return Ok(None);
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
