//! Format detection and the single entry point the CLIs call.

use std::path::{Path, PathBuf};

use crate::dataset::{Dataset, Format};
use crate::error::{DataError, Result};
use crate::options::LoadOptions;

/// What detection looks for, in order, for the error of a folder that fits no format.
const LOOKED_FOR: &str = concat!(
    "looked for transforms_train.json, transforms.json, poses_bounds.npy, ",
    "sparse/0/cameras.bin|txt (with images/), *.npz"
);

/// The format of a dataset file or folder, without loading it.
///
/// - a `.npz` file, or a folder that fits no other format and holds exactly one `.npz`: tiny npz;
/// - a folder with `transforms_train.json` or `transforms.json`: Blender, or D-NeRF when the first
///   frame of that json has a `time`;
/// - a folder with `poses_bounds.npy`: LLFF;
/// - a folder with a COLMAP model and `images/` but no `poses_bounds.npy`: COLMAP.
pub fn detect(path: &Path) -> Result<Format> {
    resolve(path).map(|(format, _)| format)
}

/// Detects the format and loads the dataset with the matching parser.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<Dataset> {
    let (format, target) = resolve(path)?;
    match format {
        Format::Blender | Format::DNerf => crate::blender::load(&target, opts),
        Format::TinyNpz => crate::tiny_npz::load(&target, opts),
        Format::Llff => crate::llff::load(&target, opts),
        Format::Colmap => crate::colmap::load(&target, opts),
        Format::NsffVideo => crate::video::load(&target, opts),
    }
}

/// Loads a dataset for the dynamic (NSFF) model: a D-NeRF folder (Blender frames with `time`) or
/// a video folder with `poses_bounds.npy`, whose frame times are their order.
pub fn load_video(path: &Path, opts: &LoadOptions) -> Result<Dataset> {
    let (format, target) = resolve(path)?;
    match format {
        Format::DNerf => crate::blender::load(&target, opts),
        Format::Llff | Format::NsffVideo => crate::video::load(&target, opts),
        Format::Blender => {
            let json = transforms_json(&target).unwrap_or_else(|| target.clone());
            Err(DataError::invalid(
                json,
                "frames without time: a Blender scene is static; the dynamic model needs D-NeRF frames with \
                 \"time\" or a video folder with poses_bounds.npy",
            ))
        }
        Format::Colmap | Format::TinyNpz => Err(DataError::invalid(
            target,
            format!(
                "a {format:?} dataset has no frame times; the dynamic model needs a D-NeRF folder (frames \
                 with \"time\") or a video folder with poses_bounds.npy"
            ),
        )),
    }
}

/// The format and the file or folder its parser takes (a folder's lone `.npz` resolves to the file).
fn resolve(path: &Path) -> Result<(Format, PathBuf)> {
    if !path.exists() {
        return Err(DataError::invalid(path, "dataset path not found"));
    }
    if path.is_file() {
        return if is_npz(path) {
            Ok((Format::TinyNpz, path.to_path_buf()))
        } else {
            Err(DataError::invalid(
                path,
                "not a dataset file: expected a .npz file, or a dataset folder (transforms_train.json, \
                 transforms.json, poses_bounds.npy or a COLMAP model with images/)",
            ))
        };
    }
    if let Some(json) = transforms_json(path) {
        let format = if crate::blender::first_frame_has_time(&json)? {
            Format::DNerf
        } else {
            Format::Blender
        };
        return Ok((format, path.to_path_buf()));
    }
    if path.join("poses_bounds.npy").is_file() {
        return Ok((Format::Llff, path.to_path_buf()));
    }
    let colmap_model = crate::colmap::find_model_dir(path);
    let has_images = path.join("images").is_dir();
    if colmap_model.is_some() && has_images {
        return Ok((Format::Colmap, path.to_path_buf()));
    }
    let npz = npz_files(path)?;
    match npz.as_slice() {
        [one] => return Ok((Format::TinyNpz, one.clone())),
        [] => {}
        many => {
            let names: Vec<String> = many
                .iter()
                .filter_map(|p| p.file_name())
                .map(|n| n.to_string_lossy().into())
                .collect();
            return Err(DataError::invalid(
                path,
                format!(
                    "holds several .npz files ({}); pass the one to load",
                    names.join(", ")
                ),
            ));
        }
    }
    let hint = match colmap_model {
        Some(model) => format!(
            "; found a COLMAP model in {} but no images/ folder",
            model.display()
        ),
        None => String::new(),
    };
    Err(DataError::invalid(
        path,
        format!("no known dataset format: {LOOKED_FOR}{hint}"),
    ))
}

/// The json that decides Blender versus D-NeRF: the train split, or the single-file layout.
fn transforms_json(dir: &Path) -> Option<PathBuf> {
    ["transforms_train.json", "transforms.json"]
        .into_iter()
        .map(|f| dir.join(f))
        .find(|p| p.is_file())
}

fn is_npz(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("npz"))
}

/// The `.npz` files directly inside `dir`, sorted.
fn npz_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))?;
    let mut out = Vec::new();
    for entry in entries {
        let p = entry.map_err(|e| DataError::io(dir, e))?.path();
        if p.is_file() && is_npz(&p) {
            out.push(p);
        }
    }
    out.sort();
    Ok(out)
}
