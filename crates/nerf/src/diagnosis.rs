//! Where the held-out error of a scene from our generator (`nerf synth`, a data folder with
//! `scene.json`) lies: on the moving objects or on the static rest, per kind of held-out view.
//!
//! Each scored view that `scene.json` describes gets a mask of the pixels whose centre ray hits a
//! moving object at the view's time (dilated by one pixel), and a group from its kind: `off_path`
//! (a camera off the video path at a training time), `mid_frame` (on the path, halfway between
//! two frames), or the kind's own name for the others. [`GroupStats`] says how to read the result.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use nerf_core::metrics::psnr_from_mse;
use nerf_data::{Camera, View};
use nerf_synth::{SCENE_FILE, Scene, SynthView};
use serde::{Deserialize, Serialize};

use crate::error::Result;

/// Error statistics of one group of held-out views.
///
/// How to read it: `area_share` is the part of the pixels the moving objects cover, and
/// `error_share` the part of the squared error found there. With error spread evenly the two
/// match. Error mostly outside the masks (`error_share` ≤ `area_share`, low `psnr_outside`) is
/// "fog": the static scene itself is wrong (floaters, haze, blur). Error concentrated in the masks
/// (`error_share` ≫ `area_share`, `psnr_inside` far below `psnr_outside`) means the movers are
/// wrong: ghosting (a blend of their positions over time) or a wrong pose at the view's time.
/// A ghost's trail, where the mover is at other times but not at this one, counts as outside.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroupStats {
    /// `off_path`, `mid_frame`, or another view kind of `scene.json` (`video`, `orbit`).
    pub group: String,
    pub views: usize,
    /// Mean of the views' PSNRs (dB).
    pub mean_psnr: f64,
    /// Mean of the views' SSIMs, when every view has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_ssim: Option<f64>,
    /// Σ squared error inside the masks / Σ squared error over all pixels; `None` when the
    /// renders are exact.
    pub error_share: Option<f64>,
    /// Pixels inside the masks / all pixels.
    pub area_share: f64,
    /// PSNR of the pooled squared error of the pixels inside the masks (`None`: no such pixel).
    pub psnr_inside: Option<f64>,
    /// PSNR of the pooled squared error of the pixels outside the masks (`None`: no such pixel).
    pub psnr_outside: Option<f64>,
}

/// Running sums of one group.
#[derive(Clone, Debug, Default)]
struct Sums {
    views: usize,
    psnr: f64,
    ssim: Option<f64>,
    /// Squared error and value count (pixels × channels) inside and outside the masks.
    err_in: f64,
    err_out: f64,
    n_in: usize,
    n_out: usize,
    px_in: usize,
    px_all: usize,
}

/// Accumulates masked views into [`GroupStats`], one per group name (sorted by name).
#[derive(Clone, Debug, Default)]
pub struct Groups(BTreeMap<String, Sums>);

impl Groups {
    /// Adds one view: its render and ground truth (`[H·W·C]`, interleaved), its mask (`[H·W]`,
    /// true inside) and its PSNR and SSIM as scored. Panics when the sizes disagree.
    pub fn add(
        &mut self,
        group: &str,
        render: &[f32],
        truth: &[f32],
        mask: &[bool],
        psnr: f64,
        ssim: Option<f64>,
    ) {
        assert_eq!(
            render.len(),
            truth.len(),
            "diagnosis: render and truth differ in size"
        );
        assert!(
            !mask.is_empty() && render.len().is_multiple_of(mask.len()),
            "diagnosis: mask does not fit the image"
        );
        let channels = render.len() / mask.len();
        let s = self.0.entry(group.to_string()).or_default();
        s.ssim = match (s.views, s.ssim, ssim) {
            (0, _, new) => new,
            (_, Some(sum), Some(new)) => Some(sum + new),
            _ => None,
        };
        s.views += 1;
        s.psnr += psnr;
        s.px_all += mask.len();
        for ((r, t), &inside) in render.chunks(channels).zip(truth.chunks(channels)).zip(mask) {
            let e: f64 = r
                .iter()
                .zip(t)
                .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
                .sum();
            if inside {
                s.err_in += e;
                s.n_in += channels;
                s.px_in += 1;
            } else {
                s.err_out += e;
                s.n_out += channels;
            }
        }
    }

    pub fn finish(self) -> Vec<GroupStats> {
        let region = |err: f64, n: usize| (n > 0).then(|| psnr_from_mse(err / n as f64));
        self.0
            .into_iter()
            .map(|(group, s)| {
                let total = s.err_in + s.err_out;
                GroupStats {
                    group,
                    views: s.views,
                    mean_psnr: s.psnr / s.views as f64,
                    mean_ssim: s.ssim.map(|sum| sum / s.views as f64),
                    error_share: (total > 0.0).then(|| s.err_in / total),
                    area_share: s.px_in as f64 / s.px_all.max(1) as f64,
                    psnr_inside: region(s.err_in, s.n_in),
                    psnr_outside: region(s.err_out, s.n_out),
                }
            })
            .collect()
    }
}

/// The generator's description of a data folder (or of the folder holding a data file), or
/// `None` when it has no `scene.json`.
pub fn load_scene(data: &Path) -> Result<Option<Scene>> {
    let dir = if data.is_file() {
        data.parent().unwrap_or(data)
    } else {
        data
    };
    let file = dir.join(SCENE_FILE);
    Ok(match file.is_file() {
        true => Some(Scene::load(&file)?),
        false => None,
    })
}

/// The scene view a dataset view was rendered from: the same file stem, and the same split when
/// the name carries its folder (`test/r_003`). `None` when there is none or the name is ambiguous.
pub fn scene_view<'a>(scene: &'a Scene, name: &str) -> Option<&'a SynthView> {
    let (folder, stem) = match name.rsplit_once('/') {
        Some((folder, stem)) => (Some(folder), stem),
        None => (None, name),
    };
    let mut found = scene
        .views
        .iter()
        .filter(|v| v.name == stem && folder.is_none_or(|f| f == v.split.as_str()));
    let view = found.next()?;
    found.next().is_none().then_some(view)
}

/// `[H·W]` pixels of `camera` whose centre ray hits a moving object at `time`, dilated by one
/// pixel (3×3), so that edge pixels, which mix the mover with what is behind it, count as the
/// mover's.
pub fn moving_mask(scene: &Scene, camera: &Camera, time: f64) -> Vec<bool> {
    let moving = scene.moving_objects();
    let ids = scene.render(camera, time).object_id;
    let hit: Vec<bool> = ids
        .iter()
        .map(|&id| usize::try_from(id).is_ok_and(|k| moving.contains(&k)))
        .collect();
    let (w, h) = (
        camera.intrinsics.width as usize,
        camera.intrinsics.height as usize,
    );
    (0..w * h)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            (y.saturating_sub(1)..(y + 2).min(h))
                .any(|yy| (x.saturating_sub(1)..(x + 2).min(w)).any(|xx| hit[yy * w + xx]))
        })
        .collect()
}

/// The diagnosis of one evaluation: [`Diagnosis::add`] every scored view, then
/// [`Diagnosis::finish`].
pub struct Diagnosis<'a> {
    scene: &'a Scene,
    groups: Groups,
}

impl<'a> Diagnosis<'a> {
    pub fn new(scene: &'a Scene) -> Self {
        Diagnosis {
            scene,
            groups: Groups::default(),
        }
    }

    /// Adds a scored view rendered as `rgb` (`[H·W·3]` at the dataset's camera). Views that
    /// `scene.json` does not describe are left out.
    pub fn add(&mut self, view: &View, rgb: &[f32], psnr: f64, ssim: Option<f64>) {
        let Some(sv) = scene_view(self.scene, &view.name) else {
            return;
        };
        let mask = moving_mask(self.scene, &view.camera, sv.time);
        self.groups
            .add(sv.kind.as_str(), rgb, &view.image.data, &mask, psnr, ssim);
    }

    /// The groups, or `None` when no view was described by the scene.
    pub fn finish(self) -> Option<Vec<GroupStats>> {
        let groups = self.groups.finish();
        (!groups.is_empty()).then_some(groups)
    }
}

/// The groups as a table for the terminal, with a line on how to read it.
pub fn table(groups: &[GroupStats]) -> String {
    let opt = |v: Option<f64>, digits: usize| v.map_or("-".to_string(), |v| format!("{v:.digits$}"));
    let mut s = String::from(
        "error on moving objects (masks from scene.json): error share >> area share = movers wrong \
         (ghosting / pose); low psnr outside = static error (fog)\n",
    );
    let _ = writeln!(
        s,
        "{:<10} {:>5} {:>8} {:>7} {:>9} {:>9} {:>12} {:>11}",
        "group", "views", "psnr", "ssim", "psnr in", "psnr out", "error share", "area share"
    );
    for g in groups {
        let _ = writeln!(
            s,
            "{:<10} {:>5} {:>8.3} {:>7} {:>9} {:>9} {:>12} {:>11.3}",
            g.group,
            g.views,
            g.mean_psnr,
            opt(g.mean_ssim, 4),
            opt(g.psnr_inside, 3),
            opt(g.psnr_outside, 3),
            opt(g.error_share, 3),
            g.area_share
        );
    }
    s
}
