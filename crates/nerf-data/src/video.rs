//! NSFF-style monocular video (method.md §4.1-4.3): frames in `images/` (or `images_N/`,
//! `images_{W}x{H}/`) with `poses_bounds.npy`, time = i / (N - 1), and the optional per-frame
//! priors NSFF's preprocessing writes: `disp/`, `flow_i1/` and `motion_masks/`.
//!
//! Poses go through the LLFF pipeline ([`crate::llff::load_with_rows`]); by default every frame
//! is a training frame, as in NSFF.

use std::path::Path;

use rayon::prelude::*;

use crate::dataset::{Dataset, FlowField, Format, VideoPriors};
use crate::error::{DataError, Result};
use crate::image::Image;
use crate::npy::NpyArray;
use crate::options::LoadOptions;

/// Loads an NSFF video folder. Priors that are absent stay `None`; priors whose size differs
/// from the training frames are errors.
pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Dataset> {
    crate::error::require_exists(dir, "video folder")?;
    let pb_path = dir.join("poses_bounds.npy");
    let mut notes = Vec::new();
    let (rows, names) = if pb_path.is_file() {
        (crate::llff::read_poses_bounds(&pb_path)?, None)
    } else if let Some(model_dir) = crate::colmap::find_model_dir(dir) {
        let model = crate::colmap::read_model(&model_dir)?;
        let pb = crate::colmap::poses_bounds(&model, &model_dir)?;
        notes.push(format!(
            "no poses_bounds.npy: computed poses and bounds from {} (LLFF's 0.1/99.9 depth percentiles)",
            model_dir.display()
        ));
        (pb.rows, Some(pb.names))
    } else {
        return Err(DataError::invalid(
            &pb_path,
            "not found: a video folder needs poses_bounds.npy (or a COLMAP sparse model) beside images/",
        ));
    };
    if rows.len() < 3 {
        return Err(DataError::invalid(
            dir,
            format!(
                "a video needs at least 3 frames, but it has {} posed frame(s)",
                rows.len()
            ),
        ));
    }
    let mut ds = crate::llff::load_with_rows(dir, &rows, names.as_deref(), opts, Format::NsffVideo)?;
    ds.notes.extend(notes);
    let n = ds.views.len();
    for (i, v) in ds.views.iter_mut().enumerate() {
        v.time = Some(i as f32 / (n - 1) as f32);
    }
    ds.priors = read_priors(dir, &ds)?;
    ds.validate()?;
    Ok(ds)
}

/// Reads whichever prior folders exist; `None` when there are none.
fn read_priors(dir: &Path, ds: &Dataset) -> Result<Option<VideoPriors>> {
    let (disp_dir, flow_dir, mask_dir) = (dir.join("disp"), dir.join("flow_i1"), dir.join("motion_masks"));
    if !disp_dir.is_dir() && !flow_dir.is_dir() && !mask_dir.is_dir() {
        return Ok(None);
    }
    let Some(first) = ds.views.first() else {
        return Ok(None);
    };
    let (w, h) = (first.image.width as usize, first.image.height as usize);
    let n = ds.views.len();
    let optional = |path: &Path| path.is_file().then(|| path.to_path_buf());

    let disparity = read_disparities(&disp_dir, &ds.views)?;
    let flow = |i: usize, dir_name: &str| {
        optional(&flow_dir.join(format!("{i:05}_{dir_name}.npz")))
            .map(|p| read_flow(&p, w, h))
            .transpose()
    };
    let flow_fwd = (0..n)
        .into_par_iter()
        .map(|i| if i + 1 < n { flow(i, "fwd") } else { Ok(None) })
        .collect::<Result<Vec<_>>>()?;
    let flow_bwd = (0..n)
        .into_par_iter()
        .map(|i| if i > 0 { flow(i, "bwd") } else { Ok(None) })
        .collect::<Result<Vec<_>>>()?;
    let motion_masks = read_motion_masks(&mask_dir, &ds.views)?;
    Ok(Some(VideoPriors {
        disparity,
        flow_fwd,
        flow_bwd,
        motion_masks,
    }))
}

/// `disp/<view name>.npy` for every view that has one (`None` for the others), each checked
/// against its own view's size.
pub(crate) fn read_disparities(
    disp_dir: &Path,
    views: &[crate::dataset::View],
) -> Result<Vec<Option<Vec<f32>>>> {
    read_per_view(disp_dir, "npy", views, read_disparity)
}

/// `motion_masks/<view name>.png` for every view that has one (`None` for the others), each
/// checked against its own view's size.
pub(crate) fn read_motion_masks(
    mask_dir: &Path,
    views: &[crate::dataset::View],
) -> Result<Vec<Option<Vec<f32>>>> {
    read_per_view(mask_dir, "png", views, read_mask)
}

/// `dir/<view name>.<ext>` read by `read(path, width, height)` for every view that has one.
fn read_per_view(
    dir: &Path,
    ext: &str,
    views: &[crate::dataset::View],
    read: fn(&Path, usize, usize) -> Result<Vec<f32>>,
) -> Result<Vec<Option<Vec<f32>>>> {
    views
        .par_iter()
        .map(|v| {
            let path = dir.join(format!("{}.{ext}", v.name));
            path.is_file()
                .then(|| read(&path, v.image.width as usize, v.image.height as usize))
                .transpose()
        })
        .collect()
}

fn shape_text(shape: &[usize]) -> String {
    shape.iter().map(|s| s.to_string()).collect::<Vec<_>>().join("x")
}

/// Checks an array's shape against `want` and that its values are finite.
fn check_array(path: &Path, what: &str, arr: &NpyArray, want: &[usize], h: usize, w: usize) -> Result<()> {
    if arr.shape != want {
        return Err(DataError::invalid(
            path,
            format!(
                "{what} is {} but frames are {h}x{w} (expected {})",
                shape_text(&arr.shape),
                shape_text(want)
            ),
        ));
    }
    if let Some(k) = arr.data.iter().position(|v| !v.is_finite()) {
        return Err(DataError::invalid(
            path,
            format!("{what} has a non-finite value at flat index {k}"),
        ));
    }
    Ok(())
}

/// `disp/<stem>.npy`: H x W (or H x W x 1) relative inverse depth.
pub fn read_disparity(path: &Path, w: usize, h: usize) -> Result<Vec<f32>> {
    let mut arr = crate::npy::read_npy(path)?;
    if arr.shape == [h, w, 1] {
        arr.shape.pop();
    }
    check_array(path, "disparity", &arr, &[h, w], h, w)?;
    Ok(arr.to_f32())
}

/// `flow_i1/NNNNN_{fwd,bwd}.npz`: `flow` H x W x 2 in pixels and `mask` H x W (bool/uint8/float).
pub fn read_flow(path: &Path, w: usize, h: usize) -> Result<FlowField> {
    let arrays = crate::npz::read_npz(path)?;
    let get = |key: &str| {
        arrays.get(key).ok_or_else(|| {
            let keys: Vec<&str> = arrays.keys().map(String::as_str).collect();
            DataError::invalid(path, format!("has no '{key}' array (it has {keys:?})"))
        })
    };
    let flow = get("flow")?;
    check_array(path, "flow", flow, &[h, w, 2], h, w)?;
    let mut mask = get("mask")?.clone();
    if mask.shape == [h, w, 1] {
        mask.shape.pop();
    }
    check_array(path, "mask", &mask, &[h, w], h, w)?;
    Ok(FlowField {
        width: w as u32,
        height: h as u32,
        flow: flow.to_f32(),
        // NSFF thresholds its masks at 1e-3.
        mask: mask
            .data
            .iter()
            .map(|&m| if m > 1e-3 { 1.0 } else { 0.0 })
            .collect(),
    })
}

/// `motion_masks/<stem>.png`: the first channel in [0, 1] (255 = probably moving).
pub fn read_mask(path: &Path, w: usize, h: usize) -> Result<Vec<f32>> {
    let img = Image::load(path)?;
    if (img.width as usize, img.height as usize) != (w, h) {
        return Err(DataError::invalid(
            path,
            format!(
                "motion mask is {}x{} but frames are {h}x{w} (HxW)",
                img.height, img.width
            ),
        ));
    }
    Ok(img
        .data
        .chunks_exact(img.channels as usize)
        .map(|px| px[0])
        .collect())
}
