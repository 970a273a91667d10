//! Rendering camera paths and camera files to PNG frames and an animated GIF.

use std::path::Path;

use nerf_data::camera::{Camera, Pose};
use nerf_data::error::{DataError, Result};
use nerf_data::math;
use nerf_data::{Dataset, Image, SceneKind};

/// A camera path to render.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PathKind {
    /// 360° orbit around the scene at the training cameras' mean radius and elevation.
    Orbit,
    /// NeRF's forward-facing spiral (LLFF scenes in NDC).
    Spiral,
    /// Along the training cameras' own path, in file order (captures that walk an arc around
    /// their subject, where a spiral about the average camera looks past it).
    Trajectory,
}

/// The default path for a scene: an orbit for objects, a spiral for forward-facing captures in
/// NDC, the capture's own trajectory for the others.
pub fn default_path(dataset: &Dataset) -> PathKind {
    match (dataset.kind, dataset.ndc.is_some()) {
        (SceneKind::Object, _) => PathKind::Orbit,
        (SceneKind::ForwardFacing, true) => PathKind::Spiral,
        (SceneKind::ForwardFacing, false) => PathKind::Trajectory,
    }
}

/// Cameras along a path, with the intrinsics of the first training view.
pub fn path_cameras(dataset: &Dataset, kind: PathKind, frames: usize) -> Vec<Camera> {
    let intrinsics = dataset.views[dataset.train.first().copied().unwrap_or(0)]
        .camera
        .intrinsics;
    let poses = match kind {
        PathKind::Spiral => nerf_data::llff::spiral_path(dataset, frames),
        PathKind::Orbit => orbit(dataset, frames),
        PathKind::Trajectory => trajectory(dataset, frames),
    };
    poses.into_iter().map(|p| Camera::new(intrinsics, p)).collect()
}

/// An orbit around the centre of the scene box, in the plane perpendicular to the mean camera
/// up vector, at the training cameras' mean distance and elevation.
pub fn orbit(dataset: &Dataset, frames: usize) -> Vec<Pose> {
    let o = OrbitFrame::of(dataset);
    (0..frames)
        .map(|k| {
            o.pose(
                std::f64::consts::TAU * k as f64 / frames.max(1) as f64,
                o.elevation,
                o.radius,
            )
        })
        .collect()
}

/// Spherical coordinates about the scene: centre of the scene box, the training cameras' mean
/// up vector, and their mean distance and elevation (what `orbit` and the viewer move on).
#[derive(Clone, Copy, Debug)]
pub struct OrbitFrame {
    pub center: math::Vec3,
    pub up: math::Vec3,
    /// Azimuth 0 and 90° directions, perpendicular to `up`.
    pub e1: math::Vec3,
    pub e2: math::Vec3,
    pub radius: f64,
    /// Radians above the plane perpendicular to `up`.
    pub elevation: f64,
}

impl OrbitFrame {
    pub fn of(dataset: &Dataset) -> Self {
        let center = [0, 1, 2].map(|a| 0.5 * (dataset.aabb[0][a] + dataset.aabb[1][a]) as f64);
        let poses: Vec<Pose> = dataset
            .train
            .iter()
            .map(|&v| dataset.views[v].camera.pose)
            .collect();
        let up = math::normalize(
            poses
                .iter()
                .fold([0.0; 3], |acc, p| math::add(acc, math::column(&p.rotation, 1))),
        );
        let n = poses.len().max(1) as f64;
        let radius = poses
            .iter()
            .map(|p| math::norm(math::sub(p.translation, center)))
            .sum::<f64>()
            / n;
        let elevation = poses
            .iter()
            .map(|p| {
                let d = math::sub(p.translation, center);
                (math::dot(d, up) / math::norm(d).max(1e-12))
                    .clamp(-1.0, 1.0)
                    .asin()
            })
            .sum::<f64>()
            / n;
        // Any unit vector perpendicular to up starts the orbit.
        let seed = if up[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        let e1 = math::normalize(math::cross(up, seed));
        let e2 = math::cross(up, e1);
        OrbitFrame {
            center,
            up,
            e1,
            e2,
            radius,
            elevation,
        }
    }

    /// A camera at (azimuth, elevation, distance) looking at the centre.
    pub fn pose(&self, azimuth: f64, elevation: f64, distance: f64) -> Pose {
        let dir = math::add(
            math::scale(
                math::add(
                    math::scale(self.e1, azimuth.cos()),
                    math::scale(self.e2, azimuth.sin()),
                ),
                elevation.cos(),
            ),
            math::scale(self.up, elevation.sin()),
        );
        Pose::look_at(
            math::add(self.center, math::scale(dir, distance)),
            self.center,
            self.up,
        )
    }

    /// (azimuth, elevation, distance) of a camera position.
    pub fn coordinates(&self, eye: math::Vec3) -> (f64, f64, f64) {
        let d = math::sub(eye, self.center);
        let r = math::norm(d).max(1e-12);
        let azimuth = math::dot(d, self.e2).atan2(math::dot(d, self.e1));
        let elevation = (math::dot(d, self.up) / r).clamp(-1.0, 1.0).asin();
        (azimuth, elevation, r)
    }
}

/// `frames` poses spaced evenly along the training cameras' path (in view order), each
/// interpolated between its two neighbouring cameras.
pub fn trajectory(dataset: &Dataset, frames: usize) -> Vec<Pose> {
    let poses: Vec<Pose> = dataset
        .train
        .iter()
        .map(|&v| dataset.views[v].camera.pose)
        .collect();
    let Some(last) = poses.len().checked_sub(1) else {
        return Vec::new();
    };
    (0..frames)
        .map(|k| {
            let u = last as f64 * k as f64 / (frames.max(2) - 1) as f64;
            let a = (u.floor() as usize).min(last.saturating_sub(1));
            poses[a].lerp(&poses[(a + 1).min(last)], u - a as f64)
        })
        .collect()
}

/// Frames rendered so far, written as they come.
pub struct FrameWriter<'a> {
    dir: &'a Path,
    frames: Vec<Image>,
    depth_range: Option<(f32, f32)>,
}

impl<'a> FrameWriter<'a> {
    /// Writes into `dir` (created), and `dir/depth`, `dir/opacity`. `depth_range` fixes the
    /// depth colour scale across frames (`None`: per frame).
    pub fn new(dir: &'a Path, depth_range: Option<(f32, f32)>) -> Result<Self> {
        for d in [dir.to_path_buf(), dir.join("depth"), dir.join("opacity")] {
            std::fs::create_dir_all(&d).map_err(|e| DataError::io(&d, e))?;
        }
        Ok(FrameWriter {
            dir,
            frames: Vec::new(),
            depth_range,
        })
    }

    /// Saves frame `k`: colour, depth (near = bright) and opacity PNGs.
    pub fn push(
        &mut self,
        k: usize,
        width: u32,
        height: u32,
        rgb: Vec<f32>,
        depth: &[f32],
        opacity: &[f32],
    ) -> Result<()> {
        let name = format!("{k:04}.png");
        let img = Image::from_data(width, height, 3, rgb);
        img.save_png(&self.dir.join(&name))?;
        depth_image(width, height, depth, opacity, self.depth_range)
            .save_png(&self.dir.join("depth").join(&name))?;
        Image::from_data(width, height, 1, opacity.to_vec())
            .save_png(&self.dir.join("opacity").join(&name))?;
        self.frames.push(img);
        Ok(())
    }

    /// Writes `name` (an animated GIF of the colour frames, 25 fps).
    pub fn finish_gif(&self, name: &str) -> Result<()> {
        let path = self.dir.join(name);
        write_gif(&path, &self.frames, 4)
    }

    /// Writes the GIF `name` and, when `ffmpeg` is on PATH, the same frames as an H.264 MP4
    /// beside it (`name` with `.mp4`). Returns a line saying what was written.
    pub fn finish(&self, name: &str) -> Result<String> {
        self.finish_gif(name)?;
        let gif = self.dir.join(name);
        let mp4 = gif.with_extension("mp4");
        Ok(if !ffmpeg_available() {
            format!("wrote {} (no ffmpeg on PATH, so no MP4)", gif.display())
        } else {
            match write_mp4(self.dir, &mp4, 25) {
                Ok(()) => format!("wrote {} and {} (H.264, ffmpeg)", gif.display(), mp4.display()),
                Err(msg) => format!("wrote {}; ffmpeg failed, so no MP4: {msg}", gif.display()),
            }
        })
    }
}

/// Whether an `ffmpeg` that runs is on PATH.
pub fn ffmpeg_available() -> bool {
    std::process::Command::new("ffmpeg")
        .arg("-version")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Encodes `frames/0000.png, 0001.png, …` as H.264 (yuv420p, sizes padded to even, as players
/// need) into `out` through a temporary file and a rename. Err: ffmpeg's own message.
pub fn write_mp4(frames: &Path, out: &Path, fps: u32) -> std::result::Result<(), String> {
    let tmp = out.with_extension("tmp.mp4");
    let result = std::process::Command::new("ffmpeg")
        .args(["-y", "-loglevel", "error", "-framerate", &fps.to_string(), "-i"])
        .arg(frames.join("%04d.png"))
        .args(["-c:v", "libx264", "-pix_fmt", "yuv420p"])
        .args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-movflags", "+faststart"])
        .arg(&tmp)
        .output()
        .map_err(|e| e.to_string())
        .and_then(|o| {
            if o.status.success() {
                std::fs::rename(&tmp, out).map_err(|e| e.to_string())
            } else {
                Err(String::from_utf8_lossy(&o.stderr).trim().to_string())
            }
        });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Depth for display, near = bright, over `range` (default: the frame's own
/// [`depth_range`]); transparent pixels black. `depth` is opacity-weighted, as renders return it.
pub fn depth_image(
    width: u32,
    height: u32,
    depth: &[f32],
    opacity: &[f32],
    range: Option<(f32, f32)>,
) -> Image {
    let (lo, hi) = range.unwrap_or_else(|| depth_range(depth, opacity));
    let d: Vec<f32> = depth
        .iter()
        .zip(opacity)
        .map(|(d, a)| {
            // Normalise the expected depth by opacity before mapping.
            let z = if *a > 1e-3 { d / a } else { hi };
            (1.0 - (z - lo) / (hi - lo).max(1e-6)).clamp(0.0, 1.0) * a.clamp(0.0, 1.0)
        })
        .collect();
    Image::from_data(width, height, 1, d)
}

/// The 2nd–98th percentile of normalised depth over mostly opaque pixels.
fn depth_range(depth: &[f32], opacity: &[f32]) -> (f32, f32) {
    let mut z: Vec<f32> = depth
        .iter()
        .zip(opacity)
        .filter(|(_, a)| **a > 0.5)
        .map(|(d, a)| d / a)
        .collect();
    if z.is_empty() {
        return (0.0, 1.0);
    }
    z.sort_by(f32::total_cmp);
    (z[z.len() / 50], z[z.len() * 49 / 50])
}

/// Animated GIF from RGB frames, `delay_cs` hundredths of a second per frame, written atomically.
pub fn write_gif(path: &Path, frames: &[Image], delay_cs: u16) -> Result<()> {
    use image::codecs::gif::{GifEncoder, Repeat};
    let mut bytes = Vec::new();
    {
        let mut enc = GifEncoder::new_with_speed(&mut bytes, 10);
        enc.set_repeat(Repeat::Infinite)
            .map_err(|e| DataError::invalid(path, e.to_string()))?;
        for f in frames {
            let rgba: Vec<u8> = f
                .data
                .chunks_exact(3)
                .flat_map(|p| {
                    [
                        nerf_data::image::to_u8(p[0]),
                        nerf_data::image::to_u8(p[1]),
                        nerf_data::image::to_u8(p[2]),
                        255,
                    ]
                })
                .collect();
            let buf = image::RgbaImage::from_raw(f.width, f.height, rgba)
                .ok_or_else(|| DataError::invalid(path, "frame size mismatch"))?;
            let frame = image::Frame::from_parts(
                buf,
                0,
                0,
                image::Delay::from_numer_denom_ms(delay_cs as u32 * 10, 1),
            );
            enc.encode_frame(frame)
                .map_err(|e| DataError::invalid(path, e.to_string()))?;
        }
    }
    nerf_data::image::write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The MP4 beside the GIF where ffmpeg exists (the developer's check; CI need not have it):
    /// odd frame sizes padded to even, every frame in the file (ffprobe counts them).
    #[test]
    fn mp4_beside_the_gif_when_ffmpeg_is_on_path() {
        if !ffmpeg_available() {
            eprintln!("skipped: no ffmpeg on PATH");
            return;
        }
        let dir = std::env::temp_dir().join(format!("nerf-mp4-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut w = FrameWriter::new(&dir, None).unwrap();
        let (width, height) = (33, 17);
        for k in 0..5 {
            let rgb = (0..3 * width * height)
                .map(|i| ((i + 7 * k) % 11) as f32 / 10.0)
                .collect();
            let ones = vec![1.0; (width * height) as usize];
            w.push(k as usize, width, height, rgb, &ones, &ones).unwrap();
        }
        let said = w.finish("path.gif").unwrap();
        assert!(said.contains("H.264"), "{said}");
        let mp4 = dir.join("path.mp4");
        assert!(dir.join("path.gif").exists() && mp4.exists());
        let probe = std::process::Command::new("ffprobe")
            .args(["-v", "error", "-count_frames", "-select_streams", "v:0"])
            .args([
                "-show_entries",
                "stream=codec_name,nb_read_frames,width,height",
                "-of",
                "csv=p=0",
            ])
            .arg(&mp4)
            .output();
        if let Ok(out) = probe {
            let text = String::from_utf8_lossy(&out.stdout);
            assert_eq!(text.trim(), "h264,34,18,5", "ffprobe: {text}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn trajectory_passes_through_every_training_camera_in_order() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/synth_static");
        let ds = nerf_data::load::load(&dir, &nerf_data::LoadOptions::default()).expect("data/synth_static");
        let n = ds.train.len();
        // 2(n − 1) + 1 frames: even frames land on the cameras, odd ones halfway between.
        let path = trajectory(&ds, 2 * (n - 1) + 1);
        assert_eq!(path.len(), 2 * n - 1);
        for (k, &v) in ds.train.iter().enumerate() {
            let (p, q) = (path[2 * k], ds.views[v].camera.pose);
            let err = p
                .rotation
                .iter()
                .flatten()
                .zip(q.rotation.iter().flatten())
                .chain(p.translation.iter().zip(q.translation.iter()))
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-9, "frame {} is not training camera {k}: {err}", 2 * k);
        }
        let (a, b) = (
            ds.views[ds.train[0]].camera.pose,
            ds.views[ds.train[1]].camera.pose,
        );
        let mid = math::scale(math::add(a.translation, b.translation), 0.5);
        assert!(math::norm(math::sub(path[1].translation, mid)) < 1e-9);
    }
}
