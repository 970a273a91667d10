//! Writes a scene as a Blender / D-NeRF folder with ground truth (layout in the crate docs).

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;

use super::disparity::{DisparityErrors, simulate};
use super::family::Variation;
use super::scene::{SCENE_FILE, Scene, Split, SynthView};
use super::{Preset, SynthConfig};
use nerf_data::camera::AxisConvention;
use nerf_data::error::{DataError, Result};
use nerf_data::image::write_atomic;

/// What [`generate`] wrote.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GenerateSummary {
    pub out_dir: PathBuf,
    pub preset: Preset,
    pub train_views: usize,
    pub test_views: usize,
    /// `transforms_val.json` lists the test images again.
    pub val_views: usize,
    /// Every file written: images, ground-truth arrays, JSON files.
    pub files_written: usize,
    /// The `family` preset: what its seed drew.
    pub variation: Option<Variation>,
}

/// Builds the scene `cfg` describes and writes it to `out_dir` (created if needed). Existing
/// files with the same names are replaced atomically; other files in `out_dir` are left alone.
pub fn generate(cfg: &SynthConfig, out_dir: &Path) -> Result<GenerateSummary> {
    cfg.validate()
        .map_err(|m| DataError::invalid(out_dir, format!("invalid synthetic scene config: {m}")))?;
    let scene = Scene::from_config(cfg);
    let mut summary = scene.write(out_dir)?;
    if let (Some(errors), true) = (cfg.mono_disparity, cfg.preset.is_video()) {
        summary.files_written += scene.write_mono_disparity(out_dir, cfg.seed, errors)?;
    }
    if cfg.motion_masks && cfg.preset.has_time() {
        summary.files_written += scene.write_motion_masks(out_dir)?;
    }
    Ok(summary)
}

/// Blender / D-NeRF `transforms_*.json`, plus nerfstudio-style explicit intrinsics.
#[derive(Serialize)]
struct TransformsJson {
    camera_angle_x: f64,
    fl_x: f64,
    fl_y: f64,
    cx: f64,
    cy: f64,
    w: u32,
    h: u32,
    frames: Vec<FrameJson>,
}

#[derive(Serialize)]
struct FrameJson {
    file_path: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    time: Option<f64>,
    transform_matrix: [[f64; 4]; 4],
    fl_x: f64,
    fl_y: f64,
    cx: f64,
    cy: f64,
    w: u32,
    h: u32,
}

fn write_f32_npy(path: &Path, shape: &[usize], data: &[f32]) -> Result<()> {
    let wide: Vec<f64> = data.iter().map(|&v| v as f64).collect();
    write_atomic(path, &nerf_data::npy::encode_npy(shape, &wide, true))
}

/// Pixels (4-neighbour steps) by which [`Scene::write_motion_masks`] grows the movers'
/// silhouettes, as NSFF dilates its masks: a segmentation's edge is not exact.
pub const MOTION_MASK_GROWTH: usize = 2;

fn gt_path(out_dir: &Path, view: &SynthView, suffix: &str) -> PathBuf {
    out_dir
        .join("gt")
        .join(view.split.as_str())
        .join(format!("{}_{suffix}.npy", view.name))
}

impl Scene {
    /// Renders every view and writes the whole folder; see the crate docs for the layout.
    pub fn write(&self, out_dir: &Path) -> Result<GenerateSummary> {
        self.validate()
            .map_err(|m| DataError::invalid(out_dir, format!("invalid synthetic scene: {m}")))?;
        let (w, h) = (self.width as usize, self.height as usize);

        // Images and depth: one task per view (each render also splits its rows).
        let per_view: Vec<usize> = self
            .views
            .par_iter()
            .map(|view| {
                let out = self.render(&self.camera(view), view.time);
                let png = out_dir
                    .join(view.split.as_str())
                    .join(format!("{}.png", view.name));
                out.rgba.save_png(&png)?;
                write_f32_npy(&gt_path(out_dir, view, "depth"), &[h, w], &out.depth)?;
                Ok(2)
            })
            .collect::<Result<_>>()?;
        let mut files: usize = per_view.iter().sum();

        // Optical flow between consecutive training frames of a video.
        let train: Vec<&SynthView> = self.views_in(Split::Train).collect();
        if self.preset.is_video() {
            let per_frame: Vec<usize> = (0..train.len())
                .into_par_iter()
                .map(|k| {
                    let neighbours = [
                        ("fwd", k.checked_add(1).filter(|&n| n < train.len())),
                        ("bwd", k.checked_sub(1)),
                    ];
                    for (dir, other) in neighbours {
                        let (flow, mask) = match other {
                            Some(n) => self.optical_flow(
                                &self.camera(train[k]),
                                train[k].time,
                                &self.camera(train[n]),
                                train[n].time,
                            ),
                            None => (vec![0.0; 2 * w * h], vec![0.0; w * h]),
                        };
                        write_f32_npy(
                            &gt_path(out_dir, train[k], &format!("flow_{dir}")),
                            &[h, w, 2],
                            &flow,
                        )?;
                        write_f32_npy(
                            &gt_path(out_dir, train[k], &format!("flow_{dir}_mask")),
                            &[h, w],
                            &mask,
                        )?;
                    }
                    Ok(4)
                })
                .collect::<Result<_>>()?;
            files += per_frame.iter().sum::<usize>();
        }

        let test: Vec<&SynthView> = self.views_in(Split::Test).collect();
        let train_json = self.transforms_json(&train);
        let test_json = self.transforms_json(&test);
        write_atomic(&out_dir.join("transforms_train.json"), train_json.as_bytes())?;
        write_atomic(&out_dir.join("transforms_test.json"), test_json.as_bytes())?;
        write_atomic(&out_dir.join("transforms_val.json"), test_json.as_bytes())?;
        write_atomic(&out_dir.join(SCENE_FILE), self.to_json().as_bytes())?;
        files += 4;

        Ok(GenerateSummary {
            out_dir: out_dir.to_path_buf(),
            preset: self.preset,
            train_views: train.len(),
            test_views: test.len(),
            val_views: test.len(),
            files_written: files,
            variation: self.variation.clone(),
        })
    }

    /// A simulated monocular disparity per training frame ([`crate::disparity::simulate`] with
    /// `errors`), written after [`Scene::write`] from its ground-truth depth to
    /// `disp/train/<name>.npy`. Returns the number of files written.
    pub fn write_mono_disparity(&self, out_dir: &Path, seed: u64, errors: DisparityErrors) -> Result<usize> {
        use rand::{SeedableRng, rngs::StdRng};
        let (w, h) = (self.width as usize, self.height as usize);
        let train: Vec<&SynthView> = self.views_in(Split::Train).collect();
        let written: Vec<usize> = train
            .par_iter()
            .enumerate()
            .map(|(k, view)| {
                let depth_path = gt_path(out_dir, view, "depth");
                let depth = nerf_data::npy::read_npy(&depth_path)?.to_f32();
                if depth.len() != w * h {
                    return Err(DataError::invalid(
                        &depth_path,
                        format!("expected {h}x{w} depths"),
                    ));
                }
                let mut rng = StdRng::seed_from_u64(seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ k as u64);
                let disp = simulate(&depth, (w, h), errors, &mut rng);
                let path = out_dir
                    .join("disp")
                    .join(view.split.as_str())
                    .join(format!("{}.npy", view.name));
                write_f32_npy(&path, &[h, w], &disp)?;
                Ok(1)
            })
            .collect::<Result<_>>()?;
        Ok(written.iter().sum())
    }

    /// Per training frame, `motion_masks/train/<name>.png`: white on the moving objects at the
    /// frame's time (the pixel-centre ray's object), grown by [`MOTION_MASK_GROWTH`] pixels (4-
    /// neighbour steps), black elsewhere. What a segmentation network that knows which objects
    /// move would give; NSFF's own masks come from one (Mask R-CNN). Returns the files written.
    pub fn write_motion_masks(&self, out_dir: &Path) -> Result<usize> {
        let (w, h) = (self.width as usize, self.height as usize);
        let movers = self.moving_objects();
        let train: Vec<&SynthView> = self.views_in(Split::Train).collect();
        let written: Vec<usize> = train
            .par_iter()
            .map(|view| {
                let ids = self.render(&self.camera(view), view.time).object_id;
                let movers_here: Vec<bool> = ids
                    .iter()
                    .map(|&i| usize::try_from(i).is_ok_and(|i| movers.contains(&i)))
                    .collect();
                let mask = nerf_data::mask::grow(&movers_here, w, h, MOTION_MASK_GROWTH);
                let mut img = nerf_data::Image::new(self.width, self.height, 1);
                for (v, &m) in img.data.iter_mut().zip(&mask) {
                    *v = if m { 1.0 } else { 0.0 };
                }
                let path = out_dir
                    .join("motion_masks")
                    .join(view.split.as_str())
                    .join(format!("{}.png", view.name));
                img.save_png(&path)?;
                Ok(1)
            })
            .collect::<Result<_>>()?;
        Ok(written.iter().sum())
    }

    /// The `transforms_*.json` text for `views` (time only for video presets).
    fn transforms_json(&self, views: &[&SynthView]) -> String {
        let k = self.intrinsics();
        let frames = views
            .iter()
            .map(|v| {
                let m = self.camera(v).pose.to_c2w(AxisConvention::OpenGl);
                FrameJson {
                    file_path: format!("./{}/{}", v.split.as_str(), v.name),
                    time: self.preset.has_time().then_some(v.time),
                    transform_matrix: [m[0], m[1], m[2], [0.0, 0.0, 0.0, 1.0]],
                    fl_x: k.fx,
                    fl_y: k.fy,
                    cx: k.cx,
                    cy: k.cy,
                    w: k.width,
                    h: k.height,
                }
            })
            .collect();
        let json = TransformsJson {
            camera_angle_x: self.camera_angle_x,
            fl_x: k.fx,
            fl_y: k.fy,
            cx: k.cx,
            cy: k.cy,
            w: k.width,
            h: k.height,
            frames,
        };
        // Plain numbers and strings: serialisation cannot fail.
        serde_json::to_string_pretty(&json).unwrap_or_default() + "\n"
    }
}
