//! LLFF captures: `poses_bounds.npy` + `images/` (or `images_N/`), loaded the way nerf-pytorch's
//! `load_llff.py` does (method.md §1.5): axis swap to OpenGL, rescale so the nearest content sits
//! at depth 1/0.75, recentre on the average pose, optional spherify, every 8th view held out, and
//! NDC rays for forward-facing scenes. Also NeRF's spiral render path.
//!
//! The pipeline lives in [`load_with_rows`], shared by the COLMAP and NSFF video loaders.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::camera::{AxisConvention, Camera, Intrinsics, Pose};
use crate::dataset::{Dataset, Format, SceneKind, View};
use crate::error::{DataError, Result};
use crate::image::Image;
use crate::math::{self, Mat3, Vec3};
use crate::ndc::Ndc;
use crate::options::{LoadOptions, NDC_MAX_VIEW_ANGLE_DEG, NdcMode};

/// LLFF's bd_factor: after rescaling, the nearest bound sits at depth 1/0.75, beyond the NDC near plane.
const BD_FACTOR: f64 = 0.75;

/// Reads and validates `poses_bounds.npy`: an N x 17 array, finite, positive focal and bounds.
pub fn read_poses_bounds(path: &Path) -> Result<Vec<[f64; 17]>> {
    let arr = crate::npy::read_npy(path)?;
    if arr.shape.len() != 2 || arr.shape[1] != 17 {
        return Err(DataError::invalid(
            path,
            format!(
                "array has shape {:?}, expected (N, 17): a row-major 3x5 pose [R | t | hwf] then near and far",
                arr.shape
            ),
        ));
    }
    if arr.shape[0] == 0 {
        return Err(DataError::invalid(path, "has no rows (no poses)"));
    }
    let rows: Vec<[f64; 17]> = arr
        .data
        .chunks_exact(17)
        .map(|c| {
            let mut r = [0.0; 17];
            r.copy_from_slice(c);
            r
        })
        .collect();
    validate_rows(path, &rows)?;
    Ok(rows)
}

/// Row checks shared by every source of rows; `origin` names the file or folder in errors.
pub(crate) fn validate_rows(origin: &Path, rows: &[[f64; 17]]) -> Result<()> {
    let bad = |k: usize, msg: String| DataError::invalid(origin, format!("row {k}: {msg}"));
    if rows.is_empty() {
        return Err(DataError::invalid(origin, "no poses"));
    }
    for (k, row) in rows.iter().enumerate() {
        if let Some(c) = row.iter().position(|v| !v.is_finite()) {
            return Err(bad(
                k,
                format!("column {c} is {} (NaN/Inf in a pose or bound)", row[c]),
            ));
        }
        let (h, w, f) = (row[4], row[9], row[14]);
        if f <= 0.0 {
            return Err(bad(k, format!("focal length {f} must be positive")));
        }
        if h < 1.0 || w < 1.0 {
            return Err(bad(
                k,
                format!("image size H={h}, W={w} must be at least 1 pixel"),
            ));
        }
        let (near, far) = (row[15], row[16]);
        if near <= 0.0 || far <= 0.0 {
            return Err(bad(
                k,
                format!("depth bounds near={near}, far={far} must be positive"),
            ));
        }
        if near > far {
            return Err(bad(k, format!("near bound {near} is beyond the far bound {far}")));
        }
        let r = row_rotation(row);
        let rtr = math::mat_mul(&math::transpose(&r), &r);
        let err = (0..3)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| (rtr[i][j] - f64::from(u8::from(i == j))).abs())
            .fold(0.0, f64::max);
        if err > 1e-3 {
            return Err(bad(
                k,
                format!("the 3x3 rotation is not orthonormal (|RᵀR - I| = {err:.2e})"),
            ));
        }
    }
    Ok(())
}

fn row_rotation(row: &[f64; 17]) -> Mat3 {
    [
        [row[0], row[1], row[2]],
        [row[5], row[6], row[7]],
        [row[10], row[11], row[12]],
    ]
}

/// The camera-to-world pose of a row, converted to OpenGL axes.
pub fn row_pose(row: &[f64; 17]) -> Pose {
    let m = [
        [row[0], row[1], row[2], row[3]],
        [row[5], row[6], row[7], row[8]],
        [row[10], row[11], row[12], row[13]],
    ];
    Pose::from_c2w(m, AxisConvention::LlffStored)
}

/// Loads an LLFF capture folder (`poses_bounds.npy` + images).
pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Dataset> {
    crate::error::require_exists(dir, "LLFF capture folder")?;
    let path = dir.join("poses_bounds.npy");
    if !path.is_file() {
        return Err(DataError::invalid(
            &path,
            "not found: an LLFF capture needs poses_bounds.npy beside its images/ folder",
        ));
    }
    let rows = read_poses_bounds(&path)?;
    load_with_rows(dir, &rows, None, opts, Format::Llff)
}

/// The LLFF pipeline on rows already in memory. `image_dir_names` (COLMAP image names, one per
/// row) selects images by name; without it the sorted image files must match the rows one to one.
/// `Format::NsffVideo` also accepts NSFF's `images_{W}x{H}/` folders and holds out nothing by default.
pub fn load_with_rows(
    dir: &Path,
    rows: &[[f64; 17]],
    image_dir_names: Option<&[String]>,
    opts: &LoadOptions,
    format: Format,
) -> Result<Dataset> {
    validate_rows(dir, rows)?;
    if let Some(names) = image_dir_names
        && names.len() != rows.len()
    {
        return Err(DataError::invalid(
            dir,
            format!("{} image names for {} poses", names.len(), rows.len()),
        ));
    }
    let nsff = format == Format::NsffVideo;
    let factor = opts.downscale.max(1);
    // One shared camera, as in LLFF: the first row's hwf.
    let (h_full, w_full, focal) = (rows[0][4], rows[0][9], rows[0][14]);
    let mut notes = Vec::new();
    let source = choose_images(
        dir,
        rows.len(),
        image_dir_names,
        factor,
        (w_full, h_full),
        nsff,
        &mut notes,
    )?;
    let (images, background) = load_images(&source, (w_full, h_full), opts)?;
    let (width, height) = check_sizes(&source, &images, (w_full, h_full), factor)?;
    let intrinsics = Intrinsics::centered(focal * width as f64 / w_full, width, height);

    // Axis swap, then rescale so that min(bounds) lands at 1/BD_FACTOR.
    let mut poses: Vec<Pose> = rows.iter().map(row_pose).collect();
    let mut bounds: Vec<[f64; 2]> = rows.iter().map(|r| [r[15], r[16]]).collect();
    let min_bound = bounds.iter().map(|b| b[0]).fold(f64::INFINITY, f64::min);
    let sc = 1.0 / (min_bound * BD_FACTOR);
    for p in &mut poses {
        p.translation = math::scale(p.translation, sc);
    }
    bounds.iter_mut().for_each(|b| *b = b.map(|v| v * sc));
    recenter(&mut poses);
    if opts.spherify {
        let s = spherify(&mut poses).ok_or_else(|| {
            DataError::invalid(
                dir,
                "cannot spherify: the camera axes are (nearly) parallel, no common focus point",
            )
        })?;
        bounds.iter_mut().for_each(|b| *b = b.map(|v| v * s));
        if opts.ndc == NdcMode::On {
            notes.push("spherify is set, so rays stay Euclidean (NDC is for forward-facing scenes)".into());
        }
    }
    let near_bound = bounds.iter().map(|b| b[0]).fold(f64::INFINITY, f64::min);
    let far_bound = bounds.iter().map(|b| b[1]).fold(f64::NEG_INFINITY, f64::max);

    let n = rows.len();
    let default_holdout = if nsff { None } else { Some(8) };
    let holdout = opts.holdout.or(default_holdout).unwrap_or(0);
    let test: Vec<usize> = if holdout > 0 {
        (0..n).step_by(holdout).collect()
    } else {
        Vec::new()
    };
    let train: Vec<usize> = (0..n).filter(|i| !test.contains(i)).collect();
    if train.is_empty() {
        return Err(DataError::invalid(
            dir,
            format!("holding out every {holdout}-th of {n} views leaves no training views"),
        ));
    }

    let views: Vec<View> = images
        .into_iter()
        .zip(&source.files)
        .zip(&poses)
        .map(|(((image, alpha), file), pose)| View {
            name: file
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            image,
            alpha,
            camera: Camera::new(intrinsics, *pose),
            time: None,
        })
        .collect();

    let use_ndc = !opts.spherify
        && match opts.ndc {
            NdcMode::On => true,
            NdcMode::Off => false,
            NdcMode::Auto => {
                let spread = view_spread_deg(&poses);
                let forward = spread <= NDC_MAX_VIEW_ANGLE_DEG;
                if !forward {
                    notes.push(format!(
                        "the cameras look up to {spread:.0}° away from their average direction (NDC needs a \
                         forward-facing capture, at most {NDC_MAX_VIEW_ANGLE_DEG:.0}°): rays stay Euclidean \
                         inside the cameras' frustum box; --ndc on forces NDC"
                    ));
                }
                forward
            }
        };
    let kind = if opts.spherify {
        SceneKind::Object
    } else {
        SceneKind::ForwardFacing
    };
    let (near, far, ndc, aabb) = if use_ndc {
        let ndc = Ndc {
            fx: intrinsics.fx,
            fy: intrinsics.fy,
            width: width as f64,
            height: height as f64,
            near: 1.0,
        };
        (0.0, 1.0, Some(ndc), [[-1.5, -1.5, -1.0], [1.5, 1.5, 1.0]])
    } else {
        let far = far_bound as f32;
        (
            (0.9 * near_bound) as f32,
            far,
            None,
            frustum_box(&views, far_bound),
        )
    };
    let ds = Dataset {
        source: dir.to_path_buf(),
        format,
        kind,
        views,
        val: test.clone(),
        train,
        test,
        near,
        far,
        depth_bounds: [near_bound as f32, far_bound as f32],
        background,
        ndc,
        aabb,
        notes,
        priors: None,
    };
    ds.validate()?;
    Ok(ds)
}

/// Where the images come from and how to bring them to the training resolution.
struct ImageSource {
    folder: PathBuf,
    files: Vec<PathBuf>,
    /// 1 = use the files as they are; f > 1 = box-downscale full-resolution files by f.
    build_factor: u32,
    /// The image size (W, H) the folder should have, from hwf; checked to ±1 px.
    expected: (f64, f64),
    /// How the expectation was derived, for error messages.
    expected_why: String,
}

/// Picks the image folder: `images_{f}/` (or, for NSFF, `images_{W}x{H}/`) when it matches the
/// poses; otherwise `images/`, downscaled in memory, with a note saying why.
fn choose_images(
    dir: &Path,
    n: usize,
    names: Option<&[String]>,
    factor: u32,
    full: (f64, f64),
    nsff: bool,
    notes: &mut Vec<String>,
) -> Result<ImageSource> {
    let f = factor as f64;
    let scaled = (full.0 / f, full.1 / f);
    let hwf_text = format!("hwf {}x{} (HxW)", full.1, full.0);
    let mut candidates: Vec<(PathBuf, (f64, f64), String)> = Vec::new();
    if factor > 1 {
        let why = format!("{hwf_text} downscaled {factor}x");
        candidates.push((dir.join(format!("images_{factor}")), scaled, why));
    }
    if nsff {
        for (folder, w, h) in wxh_folders(dir) {
            let (w, h) = (w as f64, h as f64);
            let fits = factor == 1 || ((w - scaled.0).abs() <= 1.0 && (h - scaled.1).abs() <= 1.0);
            if fits {
                let why = format!("{hwf_text} resized to the folder's width {w}");
                candidates.push((folder, (w, full.1 * w / full.0), why));
            }
        }
    }
    let mut reasons = Vec::new();
    for (folder, expected, expected_why) in candidates {
        let label = folder_label(&folder);
        if !folder.is_dir() {
            reasons.push(format!("{label} not found"));
            continue;
        }
        match match_folder(&folder, n, names)? {
            Ok(files) => {
                if factor == 1 {
                    notes.push(format!(
                        "using {label} (NSFF training resolution) instead of full-resolution images/"
                    ));
                }
                return Ok(ImageSource {
                    folder,
                    files,
                    build_factor: 1,
                    expected,
                    expected_why,
                });
            }
            Err(why) => reasons.push(why),
        }
    }
    let full_dir = dir.join("images");
    if !full_dir.is_dir() {
        let also = if reasons.is_empty() {
            String::new()
        } else {
            format!(" ({})", reasons.join("; "))
        };
        return Err(DataError::invalid(
            &full_dir,
            format!("image folder not found{also}"),
        ));
    }
    let files = match_folder(&full_dir, n, names)?.map_err(|why| {
        DataError::invalid(
            &full_dir,
            format!(
                "{why}; images are paired with poses by sorted file name, so they must correspond one to one"
            ),
        )
    })?;
    if factor > 1 {
        reasons.push(format!("built {factor}x downscaled images from images/"));
        notes.push(reasons.join("; "));
    } else if !reasons.is_empty() {
        reasons.push("using full-resolution images/".into());
        notes.push(reasons.join("; "));
    }
    Ok(ImageSource {
        folder: full_dir,
        files,
        build_factor: factor,
        expected: scaled,
        expected_why: if factor > 1 {
            format!("{hwf_text} downscaled {factor}x")
        } else {
            hwf_text
        },
    })
}

fn folder_label(folder: &Path) -> String {
    format!(
        "{}/",
        folder
            .file_name()
            .map(|s| s.to_string_lossy())
            .unwrap_or_default()
    )
}

/// NSFF's `images_{W}x{H}/` folders in `dir`, largest first.
fn wxh_folders(dir: &Path) -> Vec<(PathBuf, u32, u32)> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut out: Vec<(PathBuf, u32, u32)> = entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let (w, h) = name.strip_prefix("images_")?.split_once('x')?;
            let (w, h) = (w.parse().ok()?, h.parse().ok()?);
            e.path().is_dir().then_some((e.path(), w, h))
        })
        .collect();
    out.sort_by_key(|(_, w, h)| std::cmp::Reverse(u64::from(*w) * u64::from(*h)));
    out
}

/// Image files (png/jpg/jpeg, any case) of a folder, sorted by file name.
pub fn list_images(folder: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(folder).map_err(|e| DataError::io(folder, e))?;
    let mut files: Vec<PathBuf> = Vec::new();
    for e in entries {
        let path = e.map_err(|e| DataError::io(folder, e))?.path();
        let hidden = path
            .file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with('.'));
        let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
        if !hidden && matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg")) && path.is_file() {
            files.push(path);
        }
    }
    files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    Ok(files)
}

/// The files of `folder` for the n rows, or why the folder does not fit (outer error: unreadable).
fn match_folder(folder: &Path, n: usize, names: Option<&[String]>) -> Result<Result<Vec<PathBuf>, String>> {
    let list = list_images(folder)?;
    let label = folder_label(folder);
    let Some(names) = names else {
        return Ok(if list.len() == n {
            Ok(list)
        } else {
            Err(format!("{label} has {} images for {n} poses", list.len()))
        });
    };
    // By name: the exact relative path, else the same stem with any image extension (a
    // downscaled folder may have converted JPEGs to PNG).
    let mut files = Vec::with_capacity(n);
    let mut missing = Vec::new();
    for name in names {
        let exact = folder.join(name);
        let stem = Path::new(name).file_stem();
        if exact.is_file() {
            files.push(exact);
        } else if let Some(f) = list.iter().find(|f| f.file_stem() == stem) {
            files.push(f.clone());
        } else {
            missing.push(name.as_str());
        }
    }
    Ok(if missing.is_empty() {
        Ok(files)
    } else {
        Err(format!(
            "{label} lacks {} of the {n} posed images (first missing: {}); it has {} images",
            missing.len(),
            missing[0],
            list.len()
        ))
    })
}

type LoadedImage = (Image, Option<Vec<f32>>);

/// Loads (and where needed downscales) all images in parallel. RGBA images are composited over
/// `opts.background` when given; otherwise the alpha is dropped from the colours and kept aside.
fn load_images(
    source: &ImageSource,
    full: (f64, f64),
    opts: &LoadOptions,
) -> Result<(Vec<LoadedImage>, Option<[f32; 3]>)> {
    let mut any_alpha = false;
    let images = source
        .files
        .par_iter()
        .map(|path| {
            let img = Image::load(path)?;
            if source.build_factor > 1 {
                let (w, h) = (img.width as f64, img.height as f64);
                if (w - full.0).abs() > 1.0 || (h - full.1).abs() > 1.0 {
                    return Err(DataError::invalid(
                        path,
                        format!(
                            "image is {}x{} (WxH) but the poses' hwf says {}x{}",
                            img.width, img.height, full.0, full.1
                        ),
                    ));
                }
            }
            let img = img.downscale(source.build_factor);
            Ok(match (img.channels, opts.background) {
                (4, Some(bg)) => img.composite_alpha(bg),
                (4, None) => split_alpha(img),
                _ => (img, None),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    for (_, a) in &images {
        any_alpha |= a.is_some();
    }
    Ok((images, if any_alpha { opts.background } else { None }))
}

/// RGB without compositing, plus the alpha channel.
fn split_alpha(img: Image) -> LoadedImage {
    let mut rgb = Vec::with_capacity(img.num_pixels() * 3);
    let mut alpha = Vec::with_capacity(img.num_pixels());
    for px in img.data.chunks_exact(4) {
        rgb.extend_from_slice(&px[..3]);
        alpha.push(px[3]);
    }
    (Image::from_data(img.width, img.height, 3, rgb), Some(alpha))
}

/// All images share one size, within ±1 px of the size hwf implies.
fn check_sizes(
    source: &ImageSource,
    images: &[LoadedImage],
    full: (f64, f64),
    factor: u32,
) -> Result<(u32, u32)> {
    let (Some((first, _)), Some(first_file)) = (images.first(), source.files.first()) else {
        return Err(DataError::invalid(&source.folder, "no images"));
    };
    let (w, h) = (first.width, first.height);
    let (ew, eh) = source.expected;
    if (w as f64 - ew).abs() > 1.0 || (h as f64 - eh).abs() > 1.0 {
        return Err(DataError::invalid(
            first_file,
            format!(
                "image is {w}x{h} (WxH) but {} gives {:.1}x{:.1} (allowing ±1 px); full size {}x{}, downscale {factor}",
                source.expected_why, ew, eh, full.0, full.1
            ),
        ));
    }
    for ((img, _), file) in images.iter().zip(&source.files) {
        if (img.width, img.height) != (w, h) {
            return Err(DataError::invalid(
                file,
                format!(
                    "image is {}x{} but {} is {w}x{h}; all views must share one camera size",
                    img.width,
                    img.height,
                    first_file.display()
                ),
            ));
        }
    }
    Ok((w, h))
}

/// NeRF's `viewmatrix`: a camera with back axis along `z`, `up` roughly up, centre `pos`.
fn view_matrix(z: Vec3, up: Vec3, pos: Vec3) -> Pose {
    let back = math::normalize(z);
    let right = math::normalize(math::cross(up, back));
    let true_up = math::normalize(math::cross(back, right));
    Pose {
        rotation: math::from_columns(right, true_up, back),
        translation: pos,
    }
}

fn sum_columns(poses: &[Pose], c: usize) -> Vec3 {
    poses
        .iter()
        .fold([0.0; 3], |acc, p| math::add(acc, math::column(&p.rotation, c)))
}

/// The average pose: mean centre, summed back and up axes (NeRF's `poses_avg`).
pub fn average_pose(poses: &[Pose]) -> Pose {
    let n = poses.len().max(1) as f64;
    let centre = math::scale(
        poses
            .iter()
            .fold([0.0; 3], |acc, p| math::add(acc, p.translation)),
        1.0 / n,
    );
    view_matrix(sum_columns(poses, 2), sum_columns(poses, 1), centre)
}

/// The largest angle, in degrees, between a camera's viewing axis and the average pose's.
pub fn view_spread_deg(poses: &[Pose]) -> f64 {
    let mean_axis = math::normalize(sum_columns(poses, 2));
    poses
        .iter()
        .map(|p| {
            let axis = math::normalize(math::column(&p.rotation, 2));
            math::dot(axis, mean_axis).clamp(-1.0, 1.0).acos().to_degrees()
        })
        .fold(0.0, f64::max)
}

/// Re-expresses every pose relative to the average pose, so the mean camera sits near the origin
/// looking down -z (what NDC assumes).
fn recenter(poses: &mut [Pose]) {
    let avg = average_pose(poses);
    let inv_r = math::transpose(&avg.rotation);
    let inv_t = math::scale(math::mat_vec(&inv_r, avg.translation), -1.0);
    for p in poses.iter_mut() {
        *p = p.transformed(&inv_r, inv_t);
    }
}

/// Solves `m x = b` for a 3x3 `m` (Cramer's rule); `None` when `m` is near singular.
fn solve3(m: &Mat3, b: Vec3) -> Option<Vec3> {
    let det = |a: &Mat3| math::dot(a[0], math::cross(a[1], a[2]));
    let d = det(m);
    let scale = m.iter().flatten().map(|v| v.abs()).fold(0.0, f64::max).powi(3);
    if d.is_nan() || d.abs() <= 1e-12 * scale {
        return None;
    }
    let mut x = [0.0; 3];
    for (c, xc) in x.iter_mut().enumerate() {
        let mut mc = *m;
        for r in 0..3 {
            mc[r][c] = b[r];
        }
        *xc = det(&mc) / d;
    }
    Some(x)
}

/// NeRF's `spherify_poses` for 360° captures: moves the origin to the point nearest all optical
/// axes, aligns +z with the mean camera offset from it and scales the RMS camera radius to 1.
/// Returns the scale applied (bounds need it too), or `None` when the axes are parallel.
/// The point nearest to all cameras' optical axes (least squares); `None` when the axes are
/// (nearly) parallel, as in a forward-facing capture.
pub fn axes_focus(poses: &[Pose]) -> Option<Vec3> {
    // Point nearest to all lines (o_i, d_i): sum (I - d dᵀ) x = sum (I - d dᵀ) o.
    let mut a = [[0.0; 3]; 3];
    let mut b = [0.0; 3];
    for p in poses.iter() {
        let d = math::column(&p.rotation, 2);
        let proj: Mat3 =
            std::array::from_fn(|r| std::array::from_fn(|c| f64::from(u8::from(r == c)) - d[r] * d[c]));
        for r in 0..3 {
            for c in 0..3 {
                a[r][c] += proj[r][c];
            }
        }
        b = math::add(b, math::mat_vec(&proj, p.translation));
    }
    solve3(&a, b)
}

fn spherify(poses: &mut [Pose]) -> Option<f64> {
    let centre = axes_focus(poses)?;
    let n = poses.len() as f64;
    let up = math::scale(
        poses.iter().fold([0.0; 3], |acc, p| {
            math::add(acc, math::sub(p.translation, centre))
        }),
        1.0 / n,
    );
    let vec0 = math::normalize(up);
    let helper = if math::norm(math::cross([0.1, 0.2, 0.3], vec0)) > 1e-6 {
        [0.1, 0.2, 0.3]
    } else {
        [0.3, -0.2, 0.1]
    };
    let vec1 = math::normalize(math::cross(helper, vec0));
    let vec2 = math::normalize(math::cross(vec0, vec1));
    // World frame with columns [vec1, vec2, vec0] at `centre`; move every pose into it.
    let inv_r = math::transpose(&math::from_columns(vec1, vec2, vec0));
    let inv_t = math::scale(math::mat_vec(&inv_r, centre), -1.0);
    for p in poses.iter_mut() {
        *p = p.transformed(&inv_r, inv_t);
    }
    let rad = (poses
        .iter()
        .map(|p| math::dot(p.translation, p.translation))
        .sum::<f64>()
        / n)
        .sqrt();
    if rad.is_nan() || rad <= 0.0 {
        return None;
    }
    for p in poses.iter_mut() {
        p.translation = math::scale(p.translation, 1.0 / rad);
    }
    Some(1.0 / rad)
}

/// A box around the cameras and the corners of every view frustum at depth `far` (world units):
/// everything a ray can sample between the camera and the far bound lies inside.
fn frustum_box(views: &[View], far: f64) -> [[f32; 3]; 2] {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for v in views {
        let k = &v.camera.intrinsics;
        let (w, h) = (k.width as f64, k.height as f64);
        let corners = [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)].map(|(u, vv)| {
            let d = v.camera.direction(u, vv);
            math::add(v.camera.pose.translation, math::scale(d, far))
        });
        for p in corners.iter().chain(std::iter::once(&v.camera.pose.translation)) {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
    }
    [lo.map(|v| v as f32), hi.map(|v| v as f32)]
}

/// NeRF's forward-facing spiral render path (method.md §1.5 step 6): `frames` poses over two
/// rotations around the average camera, with radii from the 90th percentile of |camera centre|
/// per axis, looking at the focus depth derived from `depth_bounds`. Uses all views (as NeRF
/// does with all poses) in the dataset's recentred, rescaled world frame. Captures outside NDC
/// (cameras on an arc around their subject) look instead at the point their optical axes
/// converge on, when it lies in front of the average camera: NeRF's focus depth, made for
/// forward-facing scenes, lies far behind such a subject.
pub fn spiral_path(dataset: &Dataset, frames: usize) -> Vec<Pose> {
    let poses: Vec<Pose> = dataset.views.iter().map(|v| v.camera.pose).collect();
    if poses.is_empty() || frames == 0 {
        return Vec::new();
    }
    let avg = average_pose(&poses);
    let up = math::normalize(sum_columns(&poses, 1));
    let (close, inf) = (
        dataset.depth_bounds[0] as f64 * 0.9,
        dataset.depth_bounds[1] as f64 * 5.0,
    );
    let dt = 0.75;
    let focus = 1.0 / ((1.0 - dt) / close + dt / inf);
    let rads: Vec<f64> = (0..3)
        .map(|a| {
            math::percentile(
                &poses.iter().map(|p| p.translation[a].abs()).collect::<Vec<_>>(),
                90.0,
            )
        })
        .collect();
    let (rots, zrate) = (2.0, 0.5);
    let converged = dataset
        .ndc
        .is_none()
        .then(|| axes_focus(&poses))
        .flatten()
        .filter(|p| avg.to_camera(*p)[2] < 0.0);
    let target = converged.unwrap_or_else(|| avg.to_world([0.0, 0.0, -focus]));
    (0..frames)
        .map(|i| {
            let theta = 2.0 * std::f64::consts::PI * rots * i as f64 / frames as f64;
            let c = avg.to_world([
                theta.cos() * rads[0],
                -theta.sin() * rads[1],
                -(theta * zrate).sin() * rads[2],
            ]);
            view_matrix(math::sub(c, target), up, c)
        })
        .collect()
}

/// NeRF's render path for spherified (360°) captures: a circle at the cameras' mean height, on
/// the sphere of their RMS radius, looking at the origin. Unlike NeRF it does not repeat the first
/// pose at the end.
pub fn spherical_path(dataset: &Dataset, frames: usize) -> Vec<Pose> {
    let centres: Vec<Vec3> = dataset.views.iter().map(|v| v.camera.pose.translation).collect();
    if centres.is_empty() || frames == 0 {
        return Vec::new();
    }
    let n = centres.len() as f64;
    let rad = (centres.iter().map(|c| math::dot(*c, *c)).sum::<f64>() / n).sqrt();
    let zh = centres.iter().map(|c| c[2]).sum::<f64>() / n;
    let radcircle = (rad * rad - zh * zh).max(0.0).sqrt();
    (0..frames)
        .map(|i| {
            let th = 2.0 * std::f64::consts::PI * i as f64 / frames as f64;
            let origin = [radcircle * th.cos(), radcircle * th.sin(), zh];
            let back = math::normalize(origin);
            let right = math::normalize(math::cross(back, [0.0, 0.0, -1.0]));
            let up = math::normalize(math::cross(back, right));
            Pose {
                rotation: math::from_columns(right, up, back),
                translation: origin,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose_close(a: &Pose, b: &Pose, tol: f64) -> bool {
        a.rotation
            .iter()
            .flatten()
            .zip(b.rotation.iter().flatten())
            .all(|(x, y)| (x - y).abs() < tol)
            && (0..3).all(|i| (a.translation[i] - b.translation[i]).abs() < tol)
    }

    #[test]
    fn recentred_average_pose_is_identity() {
        let mut poses: Vec<Pose> = (0..5)
            .map(|i| {
                let eye = [0.3 * i as f64, 2.0 + 0.1 * i as f64, 4.0 - 0.2 * i as f64];
                Pose::look_at(eye, [0.0, 1.0, -3.0], [0.0, 1.0, 0.1])
            })
            .collect();
        recenter(&mut poses);
        assert!(pose_close(&average_pose(&poses), &Pose::identity(), 1e-12));
    }

    #[test]
    fn spherify_centres_cameras_on_the_unit_sphere_looking_inwards() {
        // Cameras on a ring of radius 3 around (1, 2, 3), all looking at it.
        let centre = [1.0, 2.0, 3.0];
        let mut poses: Vec<Pose> = (0..8)
            .map(|i| {
                let a = i as f64 * 0.7;
                let eye = [1.0 + 3.0 * a.cos(), 2.0 + 3.0 * a.sin(), 4.0];
                Pose::look_at(eye, centre, [0.0, 0.0, 1.0])
            })
            .collect();
        let s = spherify(&mut poses).unwrap();
        assert!((s - 1.0 / 10f64.sqrt()).abs() < 1e-9, "scale {s}");
        for p in &poses {
            assert!((math::norm(p.translation) - 1.0).abs() < 1e-9);
            // The back axis points away from the origin.
            let back = math::column(&p.rotation, 2);
            assert!((math::dot(back, math::normalize(p.translation)) - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn solve3_inverts() {
        let m = [[2.0, 1.0, 0.0], [0.0, 3.0, 1.0], [1.0, 0.0, 4.0]];
        let x = solve3(&m, [1.0, 2.0, 3.0]).unwrap();
        let back = math::mat_vec(&m, x);
        assert!((0..3).all(|i| (back[i] - [1.0, 2.0, 3.0][i]).abs() < 1e-12));
        assert!(
            solve3(
                &[[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
                [1.0, 1.0, 1.0]
            )
            .is_none()
        );
    }
}
