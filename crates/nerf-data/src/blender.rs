//! Blender synthetic scenes (NeRF `transforms_{train,val,test}.json`), nerfstudio/instant-ngp
//! `transforms.json`, and D-NeRF (the Blender format plus a per-frame `time`).
//!
//! Poses are camera-to-world with OpenGL axes already, so they are used as stored. RGBA images are
//! composited over the background at full resolution and only then downscaled, so edges average
//! premultiplied colour (the straight-alpha average would darken them).

use std::borrow::Cow;
use std::path::{Component, Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Deserializer};

use crate::camera::{AxisConvention, Camera, Intrinsics, Pose};
use crate::dataset::{Dataset, Format, VideoPriors, View};
use crate::error::{DataError, Result};
use crate::image::Image;
use crate::options::LoadOptions;

/// The split files of the NeRF synthetic layout, in the order their views are stored.
const SPLIT_FILES: [&str; 3] = [
    "transforms_train.json",
    "transforms_val.json",
    "transforms_test.json",
];
/// The single-file layout of nerfstudio and instant-ngp.
const SINGLE_FILE: &str = "transforms.json";
/// Held-out stride when the scene has no test json (the shared lego has only its 90 train views).
const DEFAULT_HOLDOUT: usize = 10;

/// A JSON number that may also be Python's non-standard `NaN`/`Infinity`/`-Infinity` (see
/// [`quote_non_finite`]), so such values reach validation and the error can name the frame.
#[derive(Clone, Copy, Debug)]
struct Num(f64);

impl<'de> Deserialize<'de> for Num {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        use serde::de::Error;
        match serde_json::Value::deserialize(d)? {
            serde_json::Value::Number(n) => n
                .as_f64()
                .map(Num)
                .ok_or_else(|| D::Error::custom(format!("number {n} is out of range"))),
            serde_json::Value::String(s) => match s.as_str() {
                "NaN" => Ok(Num(f64::NAN)),
                "Infinity" => Ok(Num(f64::INFINITY)),
                "-Infinity" => Ok(Num(f64::NEG_INFINITY)),
                _ => Err(D::Error::custom(format!(
                    "expected a number, found the string {s:?}"
                ))),
            },
            other => Err(D::Error::custom(format!("expected a number, found {other}"))),
        }
    }
}

/// Camera fields that may sit at file level or on each frame (nerfstudio writes both).
#[derive(Clone, Debug, Default, Deserialize)]
struct CameraFields {
    fl_x: Option<Num>,
    fl_y: Option<Num>,
    cx: Option<Num>,
    cy: Option<Num>,
    w: Option<Num>,
    h: Option<Num>,
}

impl CameraFields {
    fn is_empty(&self) -> bool {
        [self.fl_x, self.fl_y, self.cx, self.cy, self.w, self.h]
            .iter()
            .all(Option::is_none)
    }
}

#[derive(Debug, Deserialize)]
struct TransformsFile {
    camera_angle_x: Option<Num>,
    camera_angle_y: Option<Num>,
    #[serde(flatten)]
    camera: CameraFields,
    frames: Vec<FrameEntry>,
}

#[derive(Debug, Deserialize)]
struct FrameEntry {
    file_path: String,
    transform_matrix: Vec<Vec<Num>>,
    time: Option<Num>,
    #[serde(flatten)]
    camera: CameraFields,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Split {
    Train,
    Val,
    Test,
}

/// Where a frame's intrinsics come from, resolved against the actual image size once it is loaded.
#[derive(Clone, Copy, Debug)]
struct CameraSpec {
    fx: Option<f64>,
    fy: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    /// The image size the intrinsics refer to, when the json states it.
    size: Option<(u32, u32)>,
    fov_x: Option<f64>,
    fov_y: Option<f64>,
    /// The frame carries its own intrinsics, so its image may differ in size from the json's others.
    per_frame: bool,
}

/// One frame ready to load: everything from the json, checked.
#[derive(Debug)]
struct FrameJob {
    json: PathBuf,
    index: usize,
    /// `file_path` as written in the json, for messages.
    file_path: String,
    name: String,
    image_path: PathBuf,
    pose: Pose,
    time: Option<f64>,
    camera: CameraSpec,
    split: Split,
}

/// A decoded frame: RGB composited and downscaled, with its alpha and source size.
struct LoadedImage {
    image: Image,
    alpha: Option<Vec<f32>>,
    source_size: (u32, u32),
}

/// Reads whether the first frame of a transforms json carries a `time` (D-NeRF). Used by format
/// detection; the full check that every frame has one happens in [`load`].
pub fn first_frame_has_time(json: &Path) -> Result<bool> {
    let file = read_transforms(json)?;
    Ok(file.frames.first().is_some_and(|f| f.time.is_some()))
}

/// Loads a Blender synthetic or D-NeRF folder.
///
/// Reads `transforms_train.json` (required) plus `transforms_val.json` and `transforms_test.json`
/// when present, or else a single nerfstudio/instant-ngp `transforms.json`.
///
/// Split: train and val are the frames of their jsons. The test views are the frames of
/// `transforms_test.json`; when there is none (a single `transforms.json`, or a scene shipped
/// without its test json such as the shared 90-view lego) every `opts.holdout`-th frame of the
/// train json (default every 10th: indices 0, 10, 20, ...) is held out of training as the test set.
///
/// Intrinsics per frame: frame-level `fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`, else file-level ones,
/// else `camera_angle_x` (and `camera_angle_y` if given) on the actual image size, with a centred
/// principal point. RGBA images are composited over `opts.background` (white by default) and keep
/// their alpha. Frames with `time` make it a D-NeRF scene (every frame must then have one, in [0, 1]).
pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Dataset> {
    if !dir.exists() {
        return Err(DataError::invalid(dir, "Blender scene folder not found"));
    }
    if !dir.is_dir() {
        return Err(DataError::invalid(
            dir,
            "expected a Blender scene folder, found a file",
        ));
    }
    if opts.downscale == 0 {
        return Err(DataError::invalid(dir, "downscale factor must be at least 1"));
    }
    let background = opts.background.unwrap_or([1.0, 1.0, 1.0]);
    if background.iter().any(|c| !c.is_finite()) {
        return Err(DataError::invalid(
            dir,
            format!("background colour {background:?} is not finite"),
        ));
    }
    let holdout = opts.holdout.unwrap_or(DEFAULT_HOLDOUT);
    if holdout == 0 {
        return Err(DataError::invalid(
            dir,
            "holdout must be at least 1 (every n-th view is a test view)",
        ));
    }

    let mut notes = Vec::new();
    let mut jobs = Vec::new();
    let train_json = dir.join(SPLIT_FILES[0]);
    let has_test_json;
    if train_json.is_file() {
        has_test_json = dir.join(SPLIT_FILES[2]).is_file();
        for (file, split) in SPLIT_FILES.iter().zip([Split::Train, Split::Val, Split::Test]) {
            let path = dir.join(file);
            if path.is_file() {
                jobs.extend(parse_frames(&path, split)?);
            }
        }
    } else if dir.join(SINGLE_FILE).is_file() {
        has_test_json = false;
        jobs.extend(parse_frames(&dir.join(SINGLE_FILE), Split::Train)?);
    } else {
        return Err(DataError::invalid(
            dir,
            format!(
                "not a Blender scene: looked for {}, {}, {} or {SINGLE_FILE}",
                SPLIT_FILES[0], SPLIT_FILES[1], SPLIT_FILES[2]
            ),
        ));
    }
    if !has_test_json {
        let mut held = 0;
        for job in jobs.iter_mut().filter(|j| j.split == Split::Train) {
            if job.index.is_multiple_of(holdout) {
                job.split = Split::Test;
                held += 1;
            }
        }
        notes.push(format!(
            "no {}: held out every {holdout}-th training frame ({held} views) as the test set",
            SPLIT_FILES[2]
        ));
    }
    let format = check_times(&jobs)?;

    let loaded: Vec<LoadedImage> = jobs
        .par_iter()
        .map(|job| load_image(job, background, opts.downscale))
        .collect::<Result<_>>()?;
    check_sizes(&jobs, &loaded)?;

    let mut dataset = Dataset::blender_object(dir.to_path_buf(), format, background, notes);
    let mut resized_note = false;
    for (i, (job, img)) in jobs.into_iter().zip(loaded).enumerate() {
        let (intrinsics, resized) = resolve_intrinsics(&job, img.source_size, opts.downscale)?;
        if resized && !resized_note {
            resized_note = true;
            dataset.notes.push(format!(
                "{}: the json's w/h differ from the image size, intrinsics were rescaled to the images",
                job.json.display()
            ));
        }
        match job.split {
            Split::Train => dataset.train.push(i),
            Split::Val => dataset.val.push(i),
            Split::Test => dataset.test.push(i),
        }
        dataset.views.push(View {
            name: job.name,
            image: img.image,
            alpha: img.alpha,
            camera: Camera::new(intrinsics, job.pose),
            time: job.time.map(|t| t as f32),
        });
    }
    if dataset.train.is_empty() {
        return Err(DataError::invalid(
            &train_json,
            format!("no training views left (holdout {holdout} takes every frame)"),
        ));
    }
    let (disp, masks) = (dir.join("disp"), dir.join("motion_masks"));
    if format == Format::DNerf && (disp.is_dir() || masks.is_dir()) {
        // A D-NeRF video's priors: monocular disparity `disp/<split>/<stem>.npy` and motion
        // masks `motion_masks/<split>/<stem>.png` (the view's name).
        dataset.priors = Some(VideoPriors {
            disparity: crate::video::read_disparities(&disp, &dataset.views)?,
            motion_masks: crate::video::read_motion_masks(&masks, &dataset.views)?,
            ..VideoPriors::default()
        });
    }
    dataset.validate()?;
    Ok(dataset)
}

/// Parses a transforms json: its frames with checked poses, times and camera fields.
fn parse_frames(json: &Path, split: Split) -> Result<Vec<FrameJob>> {
    let file = read_transforms(json)?;
    if file.frames.is_empty() {
        return Err(DataError::invalid(json, "the json has no frames"));
    }
    let folder = json.parent().unwrap_or(Path::new("."));
    let file_fov_x = checked_angle(json, "camera_angle_x", file.camera_angle_x)?;
    let file_fov_y = checked_angle(json, "camera_angle_y", file.camera_angle_y)?;
    let file_camera = checked_camera(json, "", &file.camera)?;
    let mut jobs = Vec::with_capacity(file.frames.len());
    for (index, frame) in file.frames.into_iter().enumerate() {
        let what = format!("frame {index} ({})", frame.file_path);
        let pose = parse_pose(&frame.transform_matrix)
            .map_err(|m| DataError::invalid(json, format!("{what}: {m}")))?;
        let own = checked_camera(json, &what, &frame.camera)?;
        let camera = CameraSpec {
            fx: own.fx.or(file_camera.fx),
            fy: own.fy.or(file_camera.fy),
            cx: own.cx.or(file_camera.cx),
            cy: own.cy.or(file_camera.cy),
            size: own.size.or(file_camera.size),
            fov_x: file_fov_x,
            fov_y: file_fov_y,
            per_frame: !frame.camera.is_empty(),
        };
        if camera.fx.is_none() && camera.fy.is_none() && camera.fov_x.is_none() && camera.fov_y.is_none() {
            return Err(DataError::invalid(
                json,
                format!("{what}: no focal length (needs camera_angle_x, or fl_x at file or frame level)"),
            ));
        }
        let time = frame.time.map(|Num(t)| t);
        if let Some(t) = time {
            if !t.is_finite() {
                return Err(DataError::invalid(
                    json,
                    format!("{what}: time {t} is not finite"),
                ));
            }
            if !(0.0..=1.0).contains(&t) {
                return Err(DataError::invalid(
                    json,
                    format!("{what}: time {t} is outside [0, 1]"),
                ));
            }
        }
        jobs.push(FrameJob {
            json: json.to_path_buf(),
            index,
            name: view_name(&frame.file_path),
            image_path: image_path(folder, &frame.file_path),
            file_path: frame.file_path,
            pose,
            time,
            camera,
            split,
        });
    }
    Ok(jobs)
}

/// A camera of a transforms json, without its image (`render --cameras`).
#[derive(Clone, Debug)]
pub struct FrameCamera {
    /// `file_path` as written in the json.
    pub file_path: String,
    pub camera: Camera,
    pub time: Option<f64>,
}

/// Reads every frame's camera, in file order. Frames whose json states no image size (`w`, `h`)
/// get `default_size` (with `camera_angle_x`, the focal follows that size).
pub fn read_cameras(json: &Path, default_size: (u32, u32)) -> Result<Vec<FrameCamera>> {
    parse_frames(json, Split::Test)?
        .into_iter()
        .map(|job| {
            let size = job.camera.size.unwrap_or(default_size);
            let (intrinsics, _) = resolve_intrinsics(&job, size, 1)?;
            Ok(FrameCamera {
                file_path: job.file_path,
                camera: Camera::new(intrinsics, job.pose),
                time: job.time,
            })
        })
        .collect()
}

fn read_transforms(json: &Path) -> Result<TransformsFile> {
    let bytes = crate::error::read_file(json)?;
    let text =
        std::str::from_utf8(&bytes).map_err(|e| DataError::invalid(json, format!("not UTF-8 text: {e}")))?;
    serde_json::from_str(&quote_non_finite(text))
        .map_err(|e| DataError::invalid(json, format!("malformed JSON: {e}")))
}

/// Python's `json.dump` writes `NaN`, `Infinity` and `-Infinity`, which strict JSON rejects with
/// an unhelpful "expected value". Quoting them lets [`Num`] read them as non-finite numbers so
/// the error can say which frame holds them.
fn quote_non_finite(text: &str) -> Cow<'_, str> {
    if !text.contains("NaN") && !text.contains("Infinity") {
        return Cow::Borrowed(text);
    }
    let bytes = text.as_bytes();
    let mut out = String::with_capacity(text.len() + 16);
    let (mut in_string, mut escaped, mut copied) = (false, false, 0);
    let mut i = 0;
    while i < bytes.len() {
        let b = bytes[i];
        if in_string {
            match (escaped, b) {
                (true, _) => escaped = false,
                (false, b'\\') => escaped = true,
                (false, b'"') => in_string = false,
                _ => {}
            }
            i += 1;
            continue;
        }
        if b == b'"' {
            in_string = true;
            i += 1;
            continue;
        }
        let token = ["NaN", "Infinity", "-Infinity"]
            .into_iter()
            .find(|t| bytes[i..].starts_with(t.as_bytes()));
        match token {
            Some(t) => {
                out.push_str(&text[copied..i]);
                out.push('"');
                out.push_str(t);
                out.push('"');
                i += t.len();
                copied = i;
            }
            None => i += 1,
        }
    }
    out.push_str(&text[copied..]);
    Cow::Owned(out)
}

/// A 4x4 camera-to-world matrix (OpenGL axes) as a pose; the message says what is wrong.
fn parse_pose(m: &[Vec<Num>]) -> std::result::Result<Pose, String> {
    if m.len() != 4 || m.iter().any(|row| row.len() != 4) {
        let shape: Vec<usize> = m.iter().map(Vec::len).collect();
        return Err(format!(
            "transform_matrix must be 4x4, found rows of lengths {shape:?}"
        ));
    }
    if let Some((r, c, v)) = m
        .iter()
        .enumerate()
        .flat_map(|(r, row)| row.iter().enumerate().map(move |(c, v)| (r, c, v.0)))
        .find(|x| !x.2.is_finite())
    {
        return Err(format!(
            "transform_matrix[{r}][{c}] is {v}; a pose must be finite"
        ));
    }
    let row = |r: usize| [m[r][0].0, m[r][1].0, m[r][2].0, m[r][3].0];
    Ok(Pose::from_c2w([row(0), row(1), row(2)], AxisConvention::OpenGl))
}

/// Checked camera fields: focal lengths positive, principal point finite, size a positive integer.
fn checked_camera(json: &Path, what: &str, c: &CameraFields) -> Result<CameraSpec> {
    let prefix = if what.is_empty() {
        String::new()
    } else {
        format!("{what}: ")
    };
    let bad = |msg: String| DataError::invalid(json, format!("{prefix}{msg}"));
    let positive = |name: &str, v: Option<Num>| match v {
        Some(Num(x)) if !x.is_finite() || x <= 0.0 => {
            Err(bad(format!("{name} = {x} must be finite and positive")))
        }
        other => Ok(other.map(|n| n.0)),
    };
    let finite = |name: &str, v: Option<Num>| match v {
        Some(Num(x)) if !x.is_finite() => Err(bad(format!("{name} = {x} is not finite"))),
        other => Ok(other.map(|n| n.0)),
    };
    let pixels = |name: &str, v: Option<Num>| match v {
        Some(Num(x)) if !(x.is_finite() && x >= 1.0 && x.fract() == 0.0 && x <= u32::MAX as f64) => Err(bad(
            format!("{name} = {x} must be a positive whole number of pixels"),
        )),
        other => Ok(other.map(|n| n.0 as u32)),
    };
    let (w, h) = (pixels("w", c.w)?, pixels("h", c.h)?);
    let size = match (w, h) {
        (Some(w), Some(h)) => Some((w, h)),
        (None, None) => None,
        _ => return Err(bad("w and h must be given together".into())),
    };
    Ok(CameraSpec {
        fx: positive("fl_x", c.fl_x)?,
        fy: positive("fl_y", c.fl_y)?,
        cx: finite("cx", c.cx)?,
        cy: finite("cy", c.cy)?,
        size,
        fov_x: None,
        fov_y: None,
        per_frame: false,
    })
}

/// A field of view in radians, which must lie in (0, pi).
fn checked_angle(json: &Path, name: &str, v: Option<Num>) -> Result<Option<f64>> {
    match v {
        Some(Num(a)) if !(a.is_finite() && a > 0.0 && a < std::f64::consts::PI) => Err(DataError::invalid(
            json,
            format!("{name} = {a} must be a finite angle in (0, pi) radians"),
        )),
        other => Ok(other.map(|n| n.0)),
    }
}

/// Blender writes `file_path` without the extension and appends ".png" when loading; other
/// exporters keep the extension. A path that names an existing file is always taken as is.
fn image_path(folder: &Path, file_path: &str) -> PathBuf {
    // Drop "./" so error messages show clean paths.
    let rel: PathBuf = Path::new(file_path)
        .components()
        .filter(|c| *c != Component::CurDir)
        .collect();
    let path = folder.join(rel);
    let has_image_ext = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| ["png", "jpg", "jpeg"].iter().any(|x| e.eq_ignore_ascii_case(x)));
    if has_image_ext || path.is_file() {
        path
    } else {
        let mut s = path.into_os_string();
        s.push(".png");
        PathBuf::from(s)
    }
}

/// "./train/r_0" -> "train/r_0": unique across splits, unlike the bare stem.
fn view_name(file_path: &str) -> String {
    let p = file_path.strip_prefix("./").unwrap_or(file_path);
    let path = Path::new(p);
    match (path.parent(), path.file_stem()) {
        (Some(parent), Some(stem)) if !parent.as_os_str().is_empty() => {
            format!("{}/{}", parent.display(), stem.to_string_lossy())
        }
        (_, Some(stem)) => stem.to_string_lossy().into_owned(),
        _ => p.to_string(),
    }
}

/// Either every frame has a time (D-NeRF) or none does.
fn check_times(jobs: &[FrameJob]) -> Result<Format> {
    if jobs.iter().all(|j| j.time.is_none()) {
        return Ok(Format::Blender);
    }
    match jobs.iter().find(|j| j.time.is_none()) {
        Some(j) => Err(DataError::invalid(
            &j.json,
            format!(
                "frames without time: frame {} ({}) has no \"time\" but other frames do \
                 (D-NeRF needs one on every frame)",
                j.index, j.file_path
            ),
        )),
        None => Ok(Format::DNerf),
    }
}

/// Decodes one image, composites RGBA over the background, then downscales colour and alpha.
fn load_image(job: &FrameJob, background: [f32; 3], factor: u32) -> Result<LoadedImage> {
    let path = &job.image_path;
    if !path.is_file() {
        return Err(DataError::invalid(
            path,
            format!(
                "image not found (frame {} of {})",
                job.index,
                file_name(&job.json)
            ),
        ));
    }
    let image = Image::load(path)?;
    let source_size = (image.width, image.height);
    if image.width < factor || image.height < factor {
        return Err(DataError::invalid(
            path,
            format!(
                "image is {}x{}, smaller than the downscale factor {factor}",
                image.width, image.height
            ),
        ));
    }
    let (rgb, alpha) = image.composite_alpha(background);
    if factor == 1 {
        return Ok(LoadedImage {
            image: rgb,
            alpha,
            source_size,
        });
    }
    let alpha = alpha.map(|a| {
        Image::from_data(source_size.0, source_size.1, 1, a)
            .downscale(factor)
            .data
    });
    Ok(LoadedImage {
        image: rgb.downscale(factor),
        alpha,
        source_size,
    })
}

/// Frames of one json that rely on its shared intrinsics must have equal image sizes; a mismatch
/// is almost always a mixed-up folder, and the shared focal would be wrong for some of them.
fn check_sizes(jobs: &[FrameJob], loaded: &[LoadedImage]) -> Result<()> {
    let mut first: Vec<(&Path, &FrameJob, (u32, u32))> = Vec::new();
    for (job, img) in jobs.iter().zip(loaded) {
        if job.camera.per_frame {
            continue;
        }
        let Some(&(_, ref_job, ref_size)) = first.iter().find(|(json, ..)| *json == job.json.as_path())
        else {
            first.push((&job.json, job, img.source_size));
            continue;
        };
        if ref_size != img.source_size {
            return Err(DataError::invalid(
                &job.image_path,
                format!(
                    "{} is {}x{} but {} is {}x{} (frames of {} without per-frame intrinsics must \
                     share one size)",
                    file_name(&job.image_path),
                    img.source_size.0,
                    img.source_size.1,
                    file_name(&ref_job.image_path),
                    ref_size.0,
                    ref_size.1,
                    file_name(&job.json)
                ),
            ));
        }
    }
    Ok(())
}

/// The frame's intrinsics at the loaded (downscaled) size, and whether the json's stated size
/// differed from the image so that they had to be rescaled.
fn resolve_intrinsics(job: &FrameJob, actual: (u32, u32), factor: u32) -> Result<(Intrinsics, bool)> {
    let c = &job.camera;
    let (w, h) = c.size.unwrap_or(actual);
    let from_fov = |fov: Option<f64>, extent: u32| fov.map(|a| 0.5 * extent as f64 / (0.5 * a).tan());
    let fx = c.fx.or_else(|| from_fov(c.fov_x, w));
    let fy = c.fy.or_else(|| from_fov(c.fov_y, h));
    let (fx, fy) = match (fx, fy) {
        (Some(fx), Some(fy)) => (fx, fy),
        (Some(f), None) | (None, Some(f)) => (f, f),
        (None, None) => {
            return Err(DataError::invalid(
                &job.json,
                format!("frame {} ({}): no focal length", job.index, job.file_path),
            ));
        }
    };
    let full = Intrinsics {
        fx,
        fy,
        cx: c.cx.unwrap_or(w as f64 / 2.0),
        cy: c.cy.unwrap_or(h as f64 / 2.0),
        width: w,
        height: h,
    };
    let resized = (w, h) != actual;
    let full = if resized {
        full.resized(actual.0, actual.1)
    } else {
        full
    };
    full.validate().map_err(|m| {
        DataError::invalid(&job.json, format!("frame {} ({}): {m}", job.index, job.file_path))
    })?;
    Ok((full.downscaled(factor), resized))
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_tokens_are_quoted_outside_strings_only() {
        let text = r#"{"a": [NaN, -Infinity, Infinity, 1.5], "s": "NaN \"Infinity\""}"#;
        let fixed = quote_non_finite(text);
        assert_eq!(
            fixed,
            r#"{"a": ["NaN", "-Infinity", "Infinity", 1.5], "s": "NaN \"Infinity\""}"#
        );
        let v: Vec<Num> = serde_json::from_str(r#"["NaN", 2]"#).unwrap();
        assert!(v[0].0.is_nan() && v[1].0 == 2.0);
        assert!(matches!(quote_non_finite("{}"), Cow::Borrowed(_)));
    }

    #[test]
    fn image_paths_get_png_only_without_an_extension() {
        let dir = Path::new("/nonexistent/scene");
        assert_eq!(image_path(dir, "./train/r_0"), dir.join("train/r_0.png"));
        assert_eq!(image_path(dir, "images/a.JPG"), dir.join("images/a.JPG"));
        assert_eq!(image_path(dir, "train/r.0001"), dir.join("train/r.0001.png"));
        assert_eq!(view_name("./train/r_0"), "train/r_0");
        assert_eq!(view_name("r_0.png"), "r_0");
    }
}
