//! Held-out evaluation: PSNR and SSIM per view and their means.

use std::time::Instant;

use burn::tensor::Device;
use nerf_core::metrics::{psnr, ssim};
use nerf_data::Dataset;
use nerf_synth::Scene;
use serde::{Deserialize, Serialize};

use crate::diagnosis::{Diagnosis, GroupStats};
use crate::error::Result;
use crate::field::FieldModule;
use crate::model::StaticModel;

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ViewScore {
    pub view: usize,
    pub name: String,
    pub psnr: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ssim: Option<f64>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalResult {
    pub split: String,
    pub step: usize,
    pub train_seconds: f64,
    pub views: Vec<ViewScore>,
    pub mean_psnr: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_ssim: Option<f64>,
    /// Mean field evaluations per ray while rendering.
    pub samples_per_ray: f64,
    pub render_seconds: f64,
    /// Where the error lies, per kind of held-out view, for scenes from our generator
    /// ([`crate::diagnosis`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub groups: Option<Vec<GroupStats>>,
}

/// Up to three held-out views spread over the validation split, or over the test split when
/// there is no validation split (cheap periodic evaluation during training; the test split stays
/// for the final score, as the Blender and D-NeRF protocols have it).
pub fn quick_views(dataset: &Dataset) -> Vec<usize> {
    let t = if dataset.val.is_empty() {
        &dataset.test
    } else {
        &dataset.val
    };
    match t.len() {
        0..=3 => t.clone(),
        n => vec![t[0], t[n / 2], t[n - 1]],
    }
}

/// Renders `views` of `dataset` with `model` and scores them against their images (mean PSNR is
/// the mean of per-view PSNRs, as the NeRF papers report), optionally writing each view as
/// `DIR/<index>.png`, ground truth beside the render, and diagnosing the error by view kind when
/// `scene` (from [`crate::diagnosis::load_scene`]) describes the dataset. `step` and
/// `train_seconds` are left for the caller.
pub fn evaluate<F: FieldModule>(
    model: &StaticModel<F>,
    dataset: &Dataset,
    views: &[usize],
    with_ssim: bool,
    save: Option<&std::path::Path>,
    scene: Option<&Scene>,
    device: &Device,
) -> Result<EvalResult> {
    score_views(dataset, views, with_ssim, save, scene, |v| {
        let r = model.render_rays(&dataset.view_rays(v), dataset.background, device)?;
        Ok((r.rgb, r.samples_per_ray))
    })
}

/// Scores held-out views of `dataset` rendered by `render` (view index → RGB `[H·W·3]` and
/// samples per ray), optionally saving ground truth | render pairs as `DIR/<index>.png`. With
/// `scene`, the generator's description of the dataset, it also fills [`EvalResult::groups`].
/// `step` and `train_seconds` are left for the caller.
pub fn score_views(
    dataset: &nerf_data::Dataset,
    views: &[usize],
    with_ssim: bool,
    save: Option<&std::path::Path>,
    scene: Option<&Scene>,
    mut render: impl FnMut(usize) -> Result<(Vec<f32>, f64)>,
) -> Result<EvalResult> {
    let start = Instant::now();
    let mut scores = Vec::new();
    let mut spr = 0.0;
    let mut diagnosis = scene.map(Diagnosis::new);
    for &v in views {
        let view = &dataset.views[v];
        let (rgb, samples_per_ray) = render(v)?;
        spr += samples_per_ray;
        let (w, h) = (view.image.width as usize, view.image.height as usize);
        if let Some(dir) = save {
            let mut pair = Vec::with_capacity(2 * w * h * 3);
            for y in 0..h {
                pair.extend_from_slice(&view.image.data[y * w * 3..(y + 1) * w * 3]);
                pair.extend_from_slice(&rgb[y * w * 3..(y + 1) * w * 3]);
            }
            nerf_data::Image::from_data(2 * w as u32, h as u32, 3, pair)
                .save_png(&dir.join(format!("{v:04}.png")))?;
        }
        let score = ViewScore {
            view: v,
            name: view.name.clone(),
            psnr: psnr(&rgb, &view.image.data),
            ssim: with_ssim.then(|| ssim(&rgb, &view.image.data, w, h, 3)),
        };
        if let Some(d) = &mut diagnosis {
            d.add(view, &rgb, score.psnr, score.ssim);
        }
        scores.push(score);
    }
    let n = scores.len().max(1) as f64;
    Ok(EvalResult {
        split: "test".into(),
        step: 0,
        train_seconds: 0.0,
        mean_psnr: scores.iter().map(|s| s.psnr).sum::<f64>() / n,
        mean_ssim: with_ssim.then(|| scores.iter().filter_map(|s| s.ssim).sum::<f64>() / n),
        views: scores,
        samples_per_ray: spr / n,
        render_seconds: start.elapsed().as_secs_f64(),
        groups: diagnosis.and_then(Diagnosis::finish),
    })
}
