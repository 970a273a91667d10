//! COLMAP sparse models (`cameras`, `images`, `points3D` in `.bin` or `.txt`), LLFF's
//! `imgs2poses` (the `poses_bounds.npy` rows computed from a model), and a loader for captures
//! that have a COLMAP model but no `poses_bounds.npy`.
//!
//! COLMAP conventions (method.md §1.7): images store world-to-camera transforms
//! `X_cam = R(q)·X_world + t` with a scalar-first Hamilton quaternion, OpenCV camera axes.

use std::path::{Path, PathBuf};

use crate::dataset::{Dataset, Format};
use crate::error::{DataError, Result};
use crate::math::{self, Mat3, Vec3};
use crate::options::LoadOptions;

/// One camera of `cameras.bin`/`.txt`. `params` has the length its model needs.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    pub model_id: i32,
    pub width: u64,
    pub height: u64,
    pub params: Vec<f64>,
}

/// One registered image: a world-to-camera pose and its 2-D observations.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    /// (qw, qx, qy, qz), world-to-camera rotation.
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    pub camera_id: u32,
    pub name: String,
    /// (x, y) pixel position and the id of its 3-D point, or -1 when it has none.
    pub points2d: Vec<([f64; 2], i64)>,
}

/// One triangulated 3-D point and the images that observe it.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    pub id: u64,
    pub xyz: [f64; 3],
    pub rgb: [u8; 3],
    pub error: f64,
    /// (image_id, point2d_idx) pairs.
    pub track: Vec<(u32, u32)>,
}

/// A whole sparse model, records in file order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    pub cameras: Vec<ColmapCamera>,
    pub images: Vec<ColmapImage>,
    pub points: Vec<ColmapPoint>,
}

/// COLMAP camera model names, indexed by model id.
const MODEL_NAMES: [&str; 11] = [
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "OPENCV_FISHEYE",
    "FULL_OPENCV",
    "FOV",
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "THIN_PRISM_FISHEYE",
];

/// Number of parameters of each camera model, indexed by model id.
const MODEL_PARAMS: [usize; 11] = [3, 4, 4, 5, 8, 8, 12, 5, 4, 5, 12];

/// Parameter count of a model id, `None` for ids outside 0-10.
pub fn model_num_params(model_id: i32) -> Option<usize> {
    usize::try_from(model_id)
        .ok()
        .and_then(|i| MODEL_PARAMS.get(i).copied())
}

/// COLMAP's name of a model id (`SIMPLE_RADIAL`, ...), `None` for ids outside 0-10.
pub fn model_name(model_id: i32) -> Option<&'static str> {
    usize::try_from(model_id)
        .ok()
        .and_then(|i| MODEL_NAMES.get(i).copied())
}

impl ColmapImage {
    /// World-to-camera rotation (OpenCV camera axes).
    pub fn rotation(&self) -> Mat3 {
        math::quat_to_mat(self.qvec)
    }

    /// Camera centre in world coordinates, `C = -Rᵀ t`.
    pub fn center(&self) -> Vec3 {
        math::scale(math::mat_vec(&math::transpose(&self.rotation()), self.tvec), -1.0)
    }
}

/// The folder holding the model: `dir` itself when it has `cameras.bin`/`.txt`, else
/// `dir/sparse/0`, else `dir/sparse`.
pub fn find_model_dir(capture_or_model_dir: &Path) -> Option<PathBuf> {
    let has_model = |d: &Path| d.join("cameras.bin").is_file() || d.join("cameras.txt").is_file();
    let base = capture_or_model_dir;
    [
        base.to_path_buf(),
        base.join("sparse").join("0"),
        base.join("sparse"),
    ]
    .into_iter()
    .find(|d| has_model(d))
}

/// The `.bin` file of a model part when present, else the `.txt`; an error names both when neither exists.
fn model_file(model_dir: &Path, stem: &str) -> Result<(PathBuf, bool)> {
    let bin = model_dir.join(format!("{stem}.bin"));
    if bin.is_file() {
        return Ok((bin, true));
    }
    let txt = model_dir.join(format!("{stem}.txt"));
    if txt.is_file() {
        return Ok((txt, false));
    }
    Err(DataError::invalid(
        bin,
        format!("COLMAP model file not found (nor {stem}.txt)"),
    ))
}

/// Reads a sparse model, preferring the binary files and falling back to text, per file.
pub fn read_model(model_dir: &Path) -> Result<ColmapModel> {
    let (cam_path, cam_bin) = model_file(model_dir, "cameras")?;
    let (img_path, img_bin) = model_file(model_dir, "images")?;
    let (pts_path, pts_bin) = model_file(model_dir, "points3D")?;
    let read = |p: &Path| crate::error::read_file(p);
    let cameras = if cam_bin {
        parse_cameras_bin(&read(&cam_path)?, &cam_path)?
    } else {
        parse_cameras_txt(&read_text(&cam_path)?, &cam_path)?
    };
    let images = if img_bin {
        parse_images_bin(&read(&img_path)?, &img_path)?
    } else {
        parse_images_txt(&read_text(&img_path)?, &img_path)?
    };
    let points = if pts_bin {
        parse_points_bin(&read(&pts_path)?, &pts_path)?
    } else {
        parse_points_txt(&read_text(&pts_path)?, &pts_path)?
    };
    for im in &images {
        if !cameras.iter().any(|c| c.id == im.camera_id) {
            return Err(DataError::invalid(
                &img_path,
                format!(
                    "image {} ({}) uses camera {}, which is not in {}",
                    im.id,
                    im.name,
                    im.camera_id,
                    cam_path.display()
                ),
            ));
        }
    }
    Ok(ColmapModel {
        cameras,
        images,
        points,
    })
}

fn read_text(path: &Path) -> Result<String> {
    String::from_utf8(crate::error::read_file(path)?).map_err(|e| {
        DataError::invalid(
            path,
            format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
    })
}

// ---------------------------------------------------------------------------------------------
// Binary files

/// A little-endian cursor whose errors name the file, the byte offset and the record being read.
struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    path: &'a Path,
    kind: &'static str,
    /// Index of the record being read and the record count, once the count is known.
    record: Option<(u64, u64)>,
}

impl<'a> Reader<'a> {
    fn new(bytes: &'a [u8], path: &'a Path, kind: &'static str) -> Self {
        Reader {
            bytes,
            pos: 0,
            path,
            kind,
            record: None,
        }
    }

    fn context(&self) -> String {
        match self.record {
            Some((i, n)) => format!("{} record {i} of {n}", self.kind),
            None => format!("the number of {}s", self.kind),
        }
    }

    fn truncated(&self, at: usize) -> DataError {
        DataError::invalid(
            self.path,
            format!(
                "truncated at byte {at} while reading {} (the file has {} bytes)",
                self.context(),
                self.bytes.len()
            ),
        )
    }

    fn invalid(&self, at: usize, msg: String) -> DataError {
        DataError::invalid(
            self.path,
            format!("invalid data at byte {at} in {}: {msg}", self.context()),
        )
    }

    fn take<const N: usize>(&mut self) -> Result<[u8; N]> {
        let start = self.pos;
        let src = self
            .bytes
            .get(start..start.saturating_add(N))
            .ok_or_else(|| self.truncated(start))?;
        let mut out = [0u8; N];
        out.copy_from_slice(src);
        self.pos += N;
        Ok(out)
    }

    fn u64(&mut self) -> Result<u64> {
        self.take::<8>().map(u64::from_le_bytes)
    }

    fn i64(&mut self) -> Result<i64> {
        self.take::<8>().map(i64::from_le_bytes)
    }

    fn i32(&mut self) -> Result<i32> {
        self.take::<4>().map(i32::from_le_bytes)
    }

    fn f64(&mut self) -> Result<f64> {
        self.take::<8>().map(f64::from_le_bytes)
    }

    fn u8(&mut self) -> Result<u8> {
        self.take::<1>().map(|b| b[0])
    }

    /// An `i32` id that must be non-negative.
    fn id32(&mut self, what: &str) -> Result<u32> {
        let at = self.pos;
        let v = self.i32()?;
        u32::try_from(v).map_err(|_| self.invalid(at, format!("{what} {v} is negative")))
    }

    /// The record count, with a capacity hint bounded by what the remaining bytes can hold.
    fn count(&mut self, min_record_bytes: usize) -> Result<(u64, usize)> {
        let n = self.u64()?;
        let room = (self.bytes.len() - self.pos) / min_record_bytes.max(1);
        Ok((n, usize::try_from(n).unwrap_or(usize::MAX).min(room)))
    }

    /// Checks that `n` items of `size` bytes remain; otherwise reports the first incomplete one.
    fn need(&self, n: u64, size: usize) -> Result<()> {
        let remaining = self.bytes.len() - self.pos;
        let whole = (remaining / size) as u64;
        if n > whole {
            return Err(self.truncated(self.pos + whole as usize * size));
        }
        Ok(())
    }
}

fn parse_cameras_bin(bytes: &[u8], path: &Path) -> Result<Vec<ColmapCamera>> {
    let mut r = Reader::new(bytes, path, "camera");
    let (n, cap) = r.count(24)?;
    let mut cameras = Vec::with_capacity(cap);
    for i in 0..n {
        r.record = Some((i, n));
        let id = r.id32("camera id")?;
        let model_at = r.pos;
        let model_id = r.i32()?;
        let k = model_num_params(model_id).ok_or_else(|| {
            r.invalid(
                model_at,
                format!("camera model id {model_id} is not a COLMAP model (valid ids are 0-10)"),
            )
        })?;
        let width = r.u64()?;
        let height = r.u64()?;
        let params = (0..k).map(|_| r.f64()).collect::<Result<Vec<_>>>()?;
        cameras.push(ColmapCamera {
            id,
            model_id,
            width,
            height,
            params,
        });
    }
    Ok(cameras)
}

fn parse_images_bin(bytes: &[u8], path: &Path) -> Result<Vec<ColmapImage>> {
    let mut r = Reader::new(bytes, path, "image");
    let (n, cap) = r.count(73)?;
    let mut images = Vec::with_capacity(cap);
    for i in 0..n {
        r.record = Some((i, n));
        let id = r.id32("image id")?;
        let qvec = [r.f64()?, r.f64()?, r.f64()?, r.f64()?];
        let tvec = [r.f64()?, r.f64()?, r.f64()?];
        let camera_id = r.id32("camera id")?;
        let name_at = r.pos;
        let rest = bytes.get(name_at..).unwrap_or(&[]);
        let len = rest
            .iter()
            .position(|&c| c == 0)
            .ok_or_else(|| r.truncated(bytes.len()))?;
        let name = std::str::from_utf8(&rest[..len])
            .map_err(|_| r.invalid(name_at, "the image name is not UTF-8".into()))?
            .to_string();
        r.pos += len + 1;
        let n2d = r.u64()?;
        r.need(n2d, 24)?;
        let mut points2d = Vec::with_capacity(n2d as usize);
        for _ in 0..n2d {
            let xy = [r.f64()?, r.f64()?];
            points2d.push((xy, r.i64()?));
        }
        images.push(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        });
    }
    Ok(images)
}

fn parse_points_bin(bytes: &[u8], path: &Path) -> Result<Vec<ColmapPoint>> {
    let mut r = Reader::new(bytes, path, "point");
    let (n, cap) = r.count(51)?;
    let mut points = Vec::with_capacity(cap);
    for i in 0..n {
        r.record = Some((i, n));
        let id = r.u64()?;
        let xyz = [r.f64()?, r.f64()?, r.f64()?];
        let rgb = [r.u8()?, r.u8()?, r.u8()?];
        let error = r.f64()?;
        let len = r.u64()?;
        r.need(len, 8)?;
        let mut track = Vec::with_capacity(len as usize);
        for _ in 0..len {
            track.push((r.id32("image id")?, r.id32("point2D index")?));
        }
        points.push(ColmapPoint {
            id,
            xyz,
            rgb,
            error,
            track,
        });
    }
    Ok(points)
}

// ---------------------------------------------------------------------------------------------
// Text files

/// Non-comment lines with their 1-based line numbers. `#` starts a comment line.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

fn parse_field<T: std::str::FromStr>(path: &Path, line: usize, what: &str, tok: Option<&str>) -> Result<T> {
    let tok = tok.ok_or_else(|| DataError::invalid(path, format!("line {line}: missing {what}")))?;
    tok.parse()
        .map_err(|_| DataError::invalid(path, format!("line {line}: {what} '{tok}' is not a valid number")))
}

fn parse_cameras_txt(text: &str, path: &Path) -> Result<Vec<ColmapCamera>> {
    let mut cameras = Vec::new();
    for (ln, line) in data_lines(text) {
        let mut tok = line.split_whitespace();
        let id = parse_field(path, ln, "camera id", tok.next())?;
        let model = tok
            .next()
            .ok_or_else(|| DataError::invalid(path, format!("line {ln}: missing model")))?;
        let model_id = MODEL_NAMES
            .iter()
            .position(|m| *m == model)
            .map(|i| i as i32)
            .or_else(|| model.parse::<i32>().ok())
            .filter(|&m| model_num_params(m).is_some())
            .ok_or_else(|| DataError::invalid(path, format!("line {ln}: unknown camera model '{model}'")))?;
        let width = parse_field(path, ln, "width", tok.next())?;
        let height = parse_field(path, ln, "height", tok.next())?;
        let params = tok
            .map(|t| parse_field(path, ln, "parameter", Some(t)))
            .collect::<Result<Vec<f64>>>()?;
        let want = model_num_params(model_id).unwrap_or(0);
        if params.len() != want {
            return Err(DataError::invalid(
                path,
                format!(
                    "line {ln}: model {model} needs {want} parameters, found {}",
                    params.len()
                ),
            ));
        }
        cameras.push(ColmapCamera {
            id,
            model_id,
            width,
            height,
            params,
        });
    }
    Ok(cameras)
}

/// Splits off the first `n` whitespace-separated fields and returns them with the trimmed rest.
fn split_fields(line: &str, n: usize) -> (Vec<&str>, &str) {
    let mut fields = Vec::with_capacity(n);
    let mut rest = line.trim_start();
    while fields.len() < n && !rest.is_empty() {
        let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
        fields.push(&rest[..end]);
        rest = rest[end..].trim_start();
    }
    (fields, rest.trim_end())
}

fn parse_images_txt(text: &str, path: &Path) -> Result<Vec<ColmapImage>> {
    let lines: Vec<&str> = text.lines().collect();
    let mut images = Vec::new();
    let mut k = 0;
    while k < lines.len() {
        let (ln, line) = (k + 1, lines[k].trim());
        k += 1;
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (f, name) = split_fields(line, 9);
        if f.len() < 9 || name.is_empty() {
            return Err(DataError::invalid(
                path,
                format!(
                    "line {ln}: expected 10 fields (ID QW QX QY QZ TX TY TZ CAMERA_ID NAME), found {}",
                    f.len() + usize::from(!name.is_empty())
                ),
            ));
        }
        let num = |i: usize, what: &str| parse_field::<f64>(path, ln, what, f.get(i).copied());
        let image = ColmapImage {
            id: parse_field(path, ln, "image id", f.first().copied())?,
            qvec: [num(1, "QW")?, num(2, "QX")?, num(3, "QY")?, num(4, "QZ")?],
            tvec: [num(5, "TX")?, num(6, "TY")?, num(7, "TZ")?],
            camera_id: parse_field(path, ln, "camera id", f.get(8).copied())?,
            name: name.to_string(),
            points2d: Vec::new(),
        };
        // The observations line always follows, even when empty; a file may end without it.
        let points_ln = k + 1;
        let points_line = lines.get(k).copied().unwrap_or("");
        k += 1;
        let tok: Vec<&str> = points_line.split_whitespace().collect();
        if !tok.len().is_multiple_of(3) {
            return Err(DataError::invalid(
                path,
                format!(
                    "line {points_ln}: expected X Y POINT3D_ID triples, found {} values",
                    tok.len()
                ),
            ));
        }
        let points2d = tok
            .chunks_exact(3)
            .map(|c| {
                Ok((
                    [
                        parse_field(path, points_ln, "X", Some(c[0]))?,
                        parse_field(path, points_ln, "Y", Some(c[1]))?,
                    ],
                    parse_field(path, points_ln, "POINT3D_ID", Some(c[2]))?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        images.push(ColmapImage { points2d, ..image });
    }
    Ok(images)
}

fn parse_points_txt(text: &str, path: &Path) -> Result<Vec<ColmapPoint>> {
    let mut points = Vec::new();
    for (ln, line) in data_lines(text) {
        let tok: Vec<&str> = line.split_whitespace().collect();
        if tok.len() < 8 || !(tok.len() - 8).is_multiple_of(2) {
            return Err(DataError::invalid(
                path,
                format!(
                    "line {ln}: expected ID X Y Z R G B ERROR followed by (IMAGE_ID POINT2D_IDX) pairs, \
                         found {} values",
                    tok.len()
                ),
            ));
        }
        let f = |i: usize, what: &str| parse_field::<f64>(path, ln, what, tok.get(i).copied());
        let c = |i: usize, what: &str| parse_field::<u8>(path, ln, what, tok.get(i).copied());
        let track = tok[8..]
            .chunks_exact(2)
            .map(|p| {
                Ok((
                    parse_field(path, ln, "IMAGE_ID", Some(p[0]))?,
                    parse_field(path, ln, "POINT2D_IDX", Some(p[1]))?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        points.push(ColmapPoint {
            id: parse_field(path, ln, "point id", tok.first().copied())?,
            xyz: [f(1, "X")?, f(2, "Y")?, f(3, "Z")?],
            rgb: [c(4, "R")?, c(5, "G")?, c(6, "B")?],
            error: f(7, "ERROR")?,
            track,
        });
    }
    Ok(points)
}

// ---------------------------------------------------------------------------------------------
// Writers (fixtures, conversions). Text uses Rust's shortest round-trip float formatting, so a
// model written as text reads back bit-identical.

/// Writes `cameras.txt`, `images.txt` and `points3D.txt` into `dir` (each atomically).
pub fn write_text(model: &ColmapModel, dir: &Path) -> Result<()> {
    use std::fmt::Write;
    let mut s = String::from(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n",
    );
    for c in &model.cameras {
        let name = model_name(c.model_id).ok_or_else(|| {
            DataError::invalid(
                dir.join("cameras.txt"),
                format!("camera {}: unknown model id {}", c.id, c.model_id),
            )
        })?;
        let _ = write!(s, "{} {name} {} {}", c.id, c.width, c.height);
        for p in &c.params {
            let _ = write!(s, " {p}");
        }
        s.push('\n');
    }
    crate::image::write_atomic(&dir.join("cameras.txt"), s.as_bytes())?;

    let mut s = String::from(
        "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n\
         #   POINTS2D[] as (X, Y, POINT3D_ID)\n",
    );
    for im in &model.images {
        let [qw, qx, qy, qz] = im.qvec;
        let [tx, ty, tz] = im.tvec;
        let _ = writeln!(
            s,
            "{} {qw} {qx} {qy} {qz} {tx} {ty} {tz} {} {}",
            im.id, im.camera_id, im.name
        );
        let triples: Vec<String> = im
            .points2d
            .iter()
            .map(|([x, y], id)| format!("{x} {y} {id}"))
            .collect();
        s.push_str(&triples.join(" "));
        s.push('\n');
    }
    crate::image::write_atomic(&dir.join("images.txt"), s.as_bytes())?;

    let mut s = String::from(
        "# 3D point list with one line of data per point:\n\
         #   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n",
    );
    for p in &model.points {
        let [x, y, z] = p.xyz;
        let [r, g, b] = p.rgb;
        let _ = write!(s, "{} {x} {y} {z} {r} {g} {b} {}", p.id, p.error);
        for (im, idx) in &p.track {
            let _ = write!(s, " {im} {idx}");
        }
        s.push('\n');
    }
    crate::image::write_atomic(&dir.join("points3D.txt"), s.as_bytes())
}

/// Writes `cameras.bin`, `images.bin` and `points3D.bin` into `dir` (each atomically).
pub fn write_binary(model: &ColmapModel, dir: &Path) -> Result<()> {
    let id32 = |path: &Path, what: &str, v: u32| {
        i32::try_from(v)
            .map_err(|_| DataError::invalid(path, format!("{what} {v} does not fit COLMAP's i32")))
    };
    let path = dir.join("cameras.bin");
    let mut b = Vec::new();
    b.extend((model.cameras.len() as u64).to_le_bytes());
    for c in &model.cameras {
        b.extend(id32(&path, "camera id", c.id)?.to_le_bytes());
        b.extend(c.model_id.to_le_bytes());
        b.extend(c.width.to_le_bytes());
        b.extend(c.height.to_le_bytes());
        c.params.iter().for_each(|p| b.extend(p.to_le_bytes()));
    }
    crate::image::write_atomic(&path, &b)?;

    let path = dir.join("images.bin");
    let mut b = Vec::new();
    b.extend((model.images.len() as u64).to_le_bytes());
    for im in &model.images {
        b.extend(id32(&path, "image id", im.id)?.to_le_bytes());
        im.qvec
            .iter()
            .chain(&im.tvec)
            .for_each(|v| b.extend(v.to_le_bytes()));
        b.extend(id32(&path, "camera id", im.camera_id)?.to_le_bytes());
        b.extend(im.name.as_bytes());
        b.push(0);
        b.extend((im.points2d.len() as u64).to_le_bytes());
        for ([x, y], id) in &im.points2d {
            b.extend(x.to_le_bytes());
            b.extend(y.to_le_bytes());
            b.extend(id.to_le_bytes());
        }
    }
    crate::image::write_atomic(&path, &b)?;

    let path = dir.join("points3D.bin");
    let mut b = Vec::new();
    b.extend((model.points.len() as u64).to_le_bytes());
    for p in &model.points {
        b.extend(p.id.to_le_bytes());
        p.xyz.iter().for_each(|v| b.extend(v.to_le_bytes()));
        b.extend(p.rgb);
        b.extend(p.error.to_le_bytes());
        b.extend((p.track.len() as u64).to_le_bytes());
        for (im, idx) in &p.track {
            b.extend(id32(&path, "image id", *im)?.to_le_bytes());
            b.extend(id32(&path, "point2D index", *idx)?.to_le_bytes());
        }
    }
    crate::image::write_atomic(&path, &b)
}

// ---------------------------------------------------------------------------------------------
// LLFF imgs2poses

/// The content of a `poses_bounds.npy`, with the image name of each row.
#[derive(Clone, Debug, PartialEq)]
pub struct PosesBounds {
    /// Image names, sorted; row k belongs to `names[k]`.
    pub names: Vec<String>,
    /// `[P (3x5 row-major: [down, right, back, t, hwf]), near, far]` per image.
    pub rows: Vec<[f64; 17]>,
}

impl PosesBounds {
    /// Writes the rows as an N x 17 `<f8` `.npy`, atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        let flat: Vec<f64> = self.rows.iter().flatten().copied().collect();
        crate::npy::write_npy(path, &[self.rows.len(), 17], &flat)
    }
}

/// LLFF's `imgs2poses`: per image (sorted by name) the camera-to-world pose with stored columns
/// [down, right, back], the first camera's (H, W, f), and the 0.1 / 99.9 percentiles of the
/// camera depths of the 3-D points whose track contains the image.
///
/// Visibility is looked up by image id, not by LLFF's `id - 1` column index, so models with
/// non-contiguous ids work (identical to LLFF when ids are 1..N in file order).
pub fn poses_bounds(model: &ColmapModel, model_dir: &Path) -> Result<PosesBounds> {
    let cam = model
        .cameras
        .first()
        .ok_or_else(|| DataError::invalid(model_dir, "the COLMAP model has no cameras"))?;
    let focal = cam.params.first().copied().unwrap_or(f64::NAN);
    let hwf = [cam.height as f64, cam.width as f64, focal];
    if model.images.is_empty() {
        return Err(DataError::invalid(
            model_dir,
            "the COLMAP model has no registered images",
        ));
    }
    let mut order: Vec<&ColmapImage> = model.images.iter().collect();
    order.sort_by(|a, b| a.name.cmp(&b.name));

    // Image id -> row, for the visibility lookup.
    let mut row_of = std::collections::HashMap::with_capacity(order.len());
    for (k, im) in order.iter().enumerate() {
        if row_of.insert(im.id, k).is_some() {
            return Err(DataError::invalid(
                model_dir,
                format!("image id {} appears twice", im.id),
            ));
        }
    }
    let w2c: Vec<(Mat3, Vec3)> = order.iter().map(|im| (im.rotation(), im.tvec)).collect();
    let mut depths: Vec<Vec<f64>> = vec![Vec::new(); order.len()];
    let mut seen: Vec<usize> = Vec::new();
    for p in &model.points {
        seen.clear();
        seen.extend(p.track.iter().filter_map(|(im, _)| row_of.get(im).copied()));
        seen.sort_unstable();
        seen.dedup();
        for &k in &seen {
            let (r, t) = &w2c[k];
            depths[k].push(math::dot(r[2], p.xyz) + t[2]);
        }
    }

    let mut rows = Vec::with_capacity(order.len());
    for (k, im) in order.iter().enumerate() {
        let (r, _) = &w2c[k];
        let rt = math::transpose(r);
        let c = im.center();
        // c2w columns (OpenCV): right, down, forward. Stored: [down, right, back].
        let (right, down, fwd) = (math::column(&rt, 0), math::column(&rt, 1), math::column(&rt, 2));
        let back = math::scale(fwd, -1.0);
        let zs = &depths[k];
        if zs.is_empty() {
            return Err(DataError::invalid(
                model_dir,
                format!(
                    "image {} ({}) observes no 3-D points, so its depth bounds are undefined",
                    im.id, im.name
                ),
            ));
        }
        let mut row = [0.0; 17];
        for a in 0..3 {
            row[a * 5..a * 5 + 5].copy_from_slice(&[down[a], right[a], back[a], c[a], hwf[a]]);
        }
        row[15] = math::percentile(zs, 0.1);
        row[16] = math::percentile(zs, 99.9);
        if row[15] <= 0.0 {
            return Err(DataError::invalid(
                model_dir,
                format!(
                    "image {} ({}): the 0.1th percentile of its points' depths is {} (points behind \
                     the camera), so its near bound is not positive",
                    im.id, im.name, row[15]
                ),
            ));
        }
        rows.push(row);
    }
    let names = order.iter().map(|im| im.name.clone()).collect();
    crate::llff::validate_rows(model_dir, &rows)?;
    Ok(PosesBounds { names, rows })
}

/// Loads a capture with `images/` and a COLMAP model but no `poses_bounds.npy`: computes the
/// rows in memory, then runs the LLFF pipeline, matching images to rows by their COLMAP names.
pub fn load(capture_dir: &Path, opts: &LoadOptions) -> Result<Dataset> {
    crate::error::require_exists(capture_dir, "COLMAP capture folder")?;
    let model_dir = find_model_dir(capture_dir).ok_or_else(|| {
        DataError::invalid(
            capture_dir,
            "no COLMAP model found (looked for cameras.bin/.txt in the folder, sparse/0/ and sparse/)",
        )
    })?;
    let model = read_model(&model_dir)?;
    let pb = poses_bounds(&model, &model_dir)?;
    let mut ds = crate::llff::load_with_rows(capture_dir, &pb.rows, Some(&pb.names), opts, Format::Colmap)?;
    let Some(cam) = model.cameras.first() else {
        return Ok(ds);
    };
    let distorted = !matches!(cam.model_id, 0 | 1);
    let differing = model.cameras.iter().any(|c| c.params != cam.params);
    if distorted || differing {
        ds.notes.push(format!(
            "{}: {} camera(s); like LLFF, all views use the first camera's focal {:.2} with a centred \
             principal point{}",
            model_dir.display(),
            model.cameras.len(),
            cam.params.first().copied().unwrap_or(f64::NAN),
            if distorted {
                format!(
                    ", and its {} distortion is ignored",
                    model_name(cam.model_id).unwrap_or("?")
                )
            } else {
                String::new()
            }
        ));
    }
    Ok(ds)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// COLMAP's quaternion is scalar-first Hamilton and maps world to camera.
    #[test]
    fn quaternion_is_scalar_first_world_to_camera() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        // 90 degrees about +z: world x maps to camera y.
        let im = ColmapImage {
            id: 1,
            qvec: [h, 0.0, 0.0, h],
            tvec: [1.0, 2.0, 3.0],
            camera_id: 1,
            name: "a.png".into(),
            points2d: vec![],
        };
        let r = im.rotation();
        let x = math::mat_vec(&r, [1.0, 0.0, 0.0]);
        assert!(
            (x[0]).abs() < 1e-12 && (x[1] - 1.0).abs() < 1e-12 && x[2].abs() < 1e-12,
            "{x:?}"
        );
        // The centre maps to the camera origin.
        let c = im.center();
        let pc = math::add(math::mat_vec(&r, c), im.tvec);
        assert!(math::norm(pc) < 1e-12, "{pc:?}");
    }

    /// An identity world-to-camera looks along +z with y down; LLFF stores [down, right, back].
    #[test]
    fn imgs2poses_of_an_identity_camera() {
        let model = ColmapModel {
            cameras: vec![ColmapCamera {
                id: 3,
                model_id: 0,
                width: 40,
                height: 30,
                params: vec![50.0, 20.0, 15.0],
            }],
            images: vec![ColmapImage {
                id: 7,
                qvec: [1.0, 0.0, 0.0, 0.0],
                tvec: [0.0, 0.0, 0.0],
                camera_id: 3,
                name: "x.png".into(),
                points2d: vec![],
            }],
            points: (0..=10)
                .map(|k| ColmapPoint {
                    id: k,
                    xyz: [0.1, -0.2, 2.0 + k as f64 * 0.2],
                    rgb: [0; 3],
                    error: 0.0,
                    track: vec![(7, 0)],
                })
                .collect(),
        };
        let pb = poses_bounds(&model, Path::new("m")).unwrap();
        let r = pb.rows[0];
        let want = [
            0.0, 1.0, 0.0, 0.0, 30.0, 1.0, 0.0, 0.0, 0.0, 40.0, 0.0, 0.0, -1.0, 0.0, 50.0,
        ];
        assert_eq!(&r[..15], &want);
        assert!((r[15] - (2.0 + 0.001 * 2.0)).abs() < 1e-12, "near {}", r[15]);
        assert!((r[16] - (4.0 - 0.001 * 2.0)).abs() < 1e-12, "far {}", r[16]);
        // In OpenGL axes the camera looks along world +z with world -y up.
        let pose = crate::camera::Pose::from_c2w(
            [
                [r[0], r[1], r[2], r[3]],
                [r[5], r[6], r[7], r[8]],
                [r[10], r[11], r[12], r[13]],
            ],
            crate::camera::AxisConvention::LlffStored,
        );
        assert_eq!(math::column(&pose.rotation, 2), [0.0, 0.0, -1.0]);
        assert_eq!(math::column(&pose.rotation, 1), [0.0, -1.0, 0.0]);
    }
}
