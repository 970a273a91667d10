//! The "tiny NeRF" `.npz`: `images` (N, H, W, 3) f32 in [0, 1] on black, `poses` (N, 4, 4)
//! camera-to-world with OpenGL axes, and a 0-d `focal` in pixels (centred principal point).
//!
//! The images are already on black with no alpha, so nothing is composited here; the dataset's
//! background (black unless the user overrides it) tells the renderer what to add behind the scene.

use std::path::Path;

use crate::camera::{AxisConvention, Camera, Intrinsics, Pose};
use crate::dataset::{Dataset, Format, SceneKind, View};
use crate::error::{DataError, Result};
use crate::image::Image;
use crate::npy::NpyArray;
use crate::npz::read_npz;
use crate::options::LoadOptions;

/// Views at the end held out for testing by default: the 106-view file trains on 0..100 and
/// tests on 100..106 (view 101 is the tiny NeRF notebook's test image).
const DEFAULT_TEST_TAIL: usize = 6;
/// Hold-out stride for files too small for the tail split.
const SMALL_FILE_HOLDOUT: usize = 8;

/// Loads a tiny NeRF `.npz`.
///
/// Split: with `opts.holdout` unset and more than 6 views, the last 6 views are the test set and
/// the rest train (0..100 / 100..106 for the usual file); otherwise every `holdout`-th view
/// (default 8) is a test view. `opts.downscale` box-filters images and scales the focal.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<Dataset> {
    if !path.exists() {
        return Err(DataError::invalid(path, "tiny NeRF .npz not found"));
    }
    if opts.downscale == 0 {
        return Err(DataError::invalid(path, "downscale factor must be at least 1"));
    }
    let bad = |msg: String| DataError::invalid(path, msg);
    let arrays = read_npz(path)?;
    let get = |key: &str| {
        arrays.get(key).ok_or_else(|| {
            let present: Vec<&str> = arrays.keys().map(String::as_str).collect();
            bad(format!(
                "missing key '{key}' (keys present: {})",
                present.join(", ")
            ))
        })
    };
    let (images, poses, focal) = (get("images")?, get("poses")?, get("focal")?);

    let (n, h, w) = match images.shape[..] {
        [n, h, w, 3] if n > 0 && h > 0 && w > 0 => (n, h, w),
        _ => {
            return Err(bad(format!(
                "'images' must have shape (N, H, W, 3), found {:?}",
                images.shape
            )));
        }
    };
    let (height, width) = match (u32::try_from(h), u32::try_from(w)) {
        (Ok(h), Ok(w)) => (h, w),
        _ => return Err(bad(format!("'images' size {w}x{h} is too large"))),
    };
    let pose_rows = match poses.shape[..] {
        [pn, 3 | 4, 4] if pn == n => poses.shape[1],
        _ => {
            return Err(bad(format!(
                "'poses' must have shape ({n}, 4, 4) to match {n} images, found {:?}",
                poses.shape
            )));
        }
    };
    let focal = scalar(focal)
        .ok_or_else(|| bad(format!("'focal' must be a scalar, found shape {:?}", focal.shape)))?;
    if !focal.is_finite() || focal <= 0.0 {
        return Err(bad(format!("'focal' = {focal} must be finite and positive")));
    }
    let factor = opts.downscale;
    if width < factor || height < factor {
        return Err(bad(format!(
            "images are {width}x{height}, smaller than the downscale factor {factor}"
        )));
    }
    if let Some(i) = images.data.iter().position(|v| !v.is_finite()) {
        return Err(bad(format!(
            "'images' holds a non-finite value in view {}",
            i / (h * w * 3)
        )));
    }

    let intrinsics = Intrinsics::centered(focal, width, height).downscaled(factor);
    let mut views = Vec::with_capacity(n);
    let per_view = h * w * 3;
    for (i, (pixels, pose)) in images
        .data
        .chunks_exact(per_view)
        .zip(poses.data.chunks_exact(pose_rows * 4))
        .enumerate()
    {
        let pose = parse_pose(pose).map_err(|m| bad(format!("view {i}: {m}")))?;
        let image =
            Image::from_data(width, height, 3, pixels.iter().map(|&v| v as f32).collect()).downscale(factor);
        views.push(View {
            name: format!("{i:03}"),
            image,
            alpha: None,
            camera: Camera::new(intrinsics, pose),
            time: None,
        });
    }

    let (train, test, note) = split(n, opts.holdout).map_err(bad)?;
    let dataset = Dataset {
        source: path.to_path_buf(),
        format: Format::TinyNpz,
        kind: SceneKind::Object,
        views,
        train,
        val: Vec::new(),
        test,
        near: 2.0,
        far: 6.0,
        depth_bounds: [2.0, 6.0],
        background: Some(opts.background.unwrap_or([0.0, 0.0, 0.0])),
        ndc: None,
        aabb: [[-1.5; 3], [1.5; 3]],
        notes: vec![note],
        priors: None,
    };
    dataset.validate()?;
    Ok(dataset)
}

/// A 0-d array, or a 1-element one (some exporters write `np.array([f])`).
fn scalar(a: &NpyArray) -> Option<f64> {
    match (a.shape.as_slice(), a.data.as_slice()) {
        ([] | [1], [v]) => Some(*v),
        _ => None,
    }
}

/// Rows of a 3x4 or 4x4 camera-to-world matrix, OpenGL axes, row-major.
fn parse_pose(m: &[f64]) -> std::result::Result<Pose, String> {
    if let Some(k) = m.iter().position(|v| !v.is_finite()) {
        return Err(format!(
            "pose[{}][{}] is {}; a pose must be finite",
            k / 4,
            k % 4,
            m[k]
        ));
    }
    let row = |r: usize| [m[4 * r], m[4 * r + 1], m[4 * r + 2], m[4 * r + 3]];
    Ok(Pose::from_c2w([row(0), row(1), row(2)], AxisConvention::OpenGl))
}

/// (train, test, note) for `n` views.
fn split(n: usize, holdout: Option<usize>) -> std::result::Result<(Vec<usize>, Vec<usize>, String), String> {
    if holdout.is_none() && n > DEFAULT_TEST_TAIL {
        let cut = n - DEFAULT_TEST_TAIL;
        let note = format!("test views are the last {DEFAULT_TEST_TAIL} ({cut}..{n}), the rest train");
        return Ok(((0..cut).collect(), (cut..n).collect(), note));
    }
    let k = holdout.unwrap_or(SMALL_FILE_HOLDOUT);
    if k == 0 {
        return Err("holdout must be at least 1 (every n-th view is a test view)".into());
    }
    let (test, train): (Vec<usize>, Vec<usize>) = (0..n).partition(|i| i.is_multiple_of(k));
    if train.is_empty() {
        return Err(format!("holdout {k} leaves no training views among {n}"));
    }
    Ok((train, test, format!("every {k}-th view is a test view")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_rules() {
        let (train, test, _) = split(106, None).unwrap();
        assert_eq!((train.len(), test), (100, (100..106).collect::<Vec<_>>()));
        let (train, test, _) = split(20, Some(5)).unwrap();
        assert_eq!((train.len(), test), (16, vec![0, 5, 10, 15]));
        let (train, test, _) = split(4, None).unwrap();
        assert_eq!((train, test), (vec![1, 2, 3], vec![0]));
        assert!(split(3, Some(1)).is_err());
        assert!(split(3, Some(0)).is_err());
    }
}
