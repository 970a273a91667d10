//! The training video: frames ordered by time, their neighbours, and the optical-flow priors
//! (read from the input, or computed with the built-in estimator and cached in the run folder).

use std::path::Path;

use nerf_data::error::{DataError, Result};
use nerf_data::{Dataset, FlowField};

use crate::capture::{self, CameraPath};

/// A video ready for NSFF.
pub struct Video {
    pub dataset: Dataset,
    /// Training view indices in time order.
    pub frames: Vec<usize>,
    /// Normalised time of each frame, increasing.
    pub times: Vec<f32>,
    /// Optical flow frame k → k+1 (None for the last frame), at the frames' resolution.
    pub flow_fwd: Vec<Option<FlowField>>,
    /// Optical flow frame k → k−1 (None for the first frame).
    pub flow_bwd: Vec<Option<FlowField>>,
    /// Monocular disparity per frame, when the input had it.
    pub disparity: Vec<Option<Vec<f32>>>,
    /// Smooth video or jumping camera, from the poses.
    pub camera_path: CameraPath,
    /// Share of flow pixels the camera motion does not explain, and the decision (a jumping
    /// camera has no flow: no fraction, and the decision is "moving").
    pub moving_fraction: Option<f32>,
    pub has_motion: bool,
    /// Per frame, its motion mask (`[H*W]` row-major, true = probably moving; the static batch
    /// draws from outside it): the masks given with the video, or else the flow test's.
    pub motion_masks: Vec<Vec<bool>>,
    /// Per frame, the pixels marked as moving (what hard mining draws from): the motion mask's
    /// (given or the flow test's), and with `unmask_background` the background pixels it left out.
    pub moving_pixels: Vec<Vec<u32>>,
    /// Whether the masks were given with the video (`motion_masks/`) rather than computed from
    /// the flow.
    pub masks_given: bool,
    /// Whether masks were given but are not used: a jumping camera trains without them (its
    /// settings were screened so).
    pub masks_ignored: bool,
}

impl Video {
    /// Share of all frames' pixels inside their motion masks.
    pub fn mask_fraction(&self) -> f32 {
        let (inside, all) = self.motion_masks.iter().fold((0usize, 0usize), |(a, b), m| {
            (a + m.iter().filter(|&&x| x).count(), b + m.len())
        });
        inside as f32 / all.max(1) as f32
    }
}

/// Orders the training frames by time and checks them: every frame has a time, times strictly
/// increase in file order (no duplicates), all frames share one size, and there are at least 3.
pub fn check_frames(dataset: &Dataset) -> Result<(Vec<usize>, Vec<f32>)> {
    let source = train_json(dataset);
    let frames = dataset.train.clone();
    if frames.len() < 3 {
        return Err(DataError::invalid(
            &source,
            format!("NSFF needs at least 3 training frames, found {}", frames.len()),
        ));
    }
    let mut times = Vec::with_capacity(frames.len());
    for (k, &v) in frames.iter().enumerate() {
        let view = &dataset.views[v];
        let t = view.time.ok_or_else(|| {
            DataError::invalid(
                &source,
                format!(
                    "frame {k} ({}) has no time; NSFF needs a time per frame",
                    view.name
                ),
            )
        })?;
        if let Some(&prev) = times.last() {
            if t == prev {
                return Err(DataError::invalid(
                    &source,
                    format!("frames {} and {k} ({}) have the same time {t}", k - 1, view.name),
                ));
            }
            if t < prev {
                return Err(DataError::invalid(
                    &source,
                    format!(
                        "time decreases at frame {k} ({}): {t} after {prev}; frames must be in time order",
                        view.name
                    ),
                ));
            }
        }
        times.push(t);
        let (w, h) = (view.image.width, view.image.height);
        let first = &dataset.views[frames[0]].image;
        if (w, h) != (first.width, first.height) {
            return Err(DataError::invalid(
                &source,
                format!(
                    "frame {k} ({}) is {w}x{h} but frame 0 is {}x{}",
                    view.name, first.width, first.height
                ),
            ));
        }
    }
    Ok((frames, times))
}

/// Clears the mask (`[H*W]`) wherever the frame's `alpha` is 0: the ray sees only the
/// background, so no mover is on it, and the static batch should learn that it is empty. The flow
/// test cannot tell: the background has no texture to match, and its flow, smoothed in from the
/// scene's silhouette, leaves the epipolar lines there.
pub fn unmask_background(mask: &mut [bool], alpha: &[f32]) {
    for (m, &a) in mask.iter_mut().zip(alpha) {
        *m &= a > 0.0;
    }
}

/// The file frames come from, for messages (`transforms_train.json` or the folder).
fn train_json(dataset: &Dataset) -> std::path::PathBuf {
    let json = dataset.source.join("transforms_train.json");
    if json.exists() {
        json
    } else {
        dataset.source.clone()
    }
}

/// Each frame's entry of a per-view prior, taken out of `v` in frame order; a view the prior
/// does not reach gives `None`.
fn take_in_frame_order<T>(v: &mut [Option<T>], frames: &[usize]) -> Vec<Option<T>> {
    frames
        .iter()
        .map(|&f| v.get_mut(f).and_then(Option::take))
        .collect()
}

/// Prepares the video: frame order, flows (given, cached or computed), motion decision. A
/// jumping camera ([`capture::classify`]) gets neither flows nor masks.
/// Epipolar errors above `motion_threshold_px` count as motion for the decision; `masks` marks
/// the per-frame motion masks, and with `unmask_background` the pixels of RGBA frames whose
/// alpha is 0 are kept out of them ([`unmask_background`]).
pub fn prepare(
    mut dataset: Dataset,
    cache_dir: &Path,
    motion_threshold_px: f32,
    masks: nerf_flow::MaskRule,
    unmask_background: bool,
    quiet: bool,
) -> Result<Video> {
    let (frames, times) = check_frames(&dataset)?;
    let n = frames.len();
    let cameras: Vec<nerf_data::Camera> = frames.iter().map(|&f| dataset.views[f].camera).collect();
    let depth = 0.5 * (dataset.depth_bounds[0] + dataset.depth_bounds[1]) as f64;
    let camera_path = capture::classify(&cameras, depth);
    // Taken, not cloned: from here the video holds the priors it uses, in frame order.
    let mut given = dataset.priors.take().unwrap_or_default();
    let disparity = take_in_frame_order(&mut given.disparity, &frames);
    if camera_path.is_jumping() {
        let masks_ignored = given_motion_masks(&dataset, &frames, &given)?.is_some();
        let mut video = jumping(dataset, frames, times, disparity, camera_path);
        video.masks_ignored = masks_ignored;
        return Ok(video);
    }
    let mut flow_fwd = take_in_frame_order(&mut given.flow_fwd, &frames);
    let mut flow_bwd = take_in_frame_order(&mut given.flow_bwd, &frames);
    let complete = (0..n).all(|k| (k + 1 == n || flow_fwd[k].is_some()) && (k == 0 || flow_bwd[k].is_some()));
    if !complete {
        let first = &dataset.views[frames[0]].image;
        let (w, h) = (first.width, first.height);
        let images: Vec<&nerf_data::Image> = frames.iter().map(|&f| &dataset.views[f].image).collect();
        let params = nerf_flow::FlowParams::default();
        let key = nerf_flow::cache_key(&images, &params);
        match nerf_flow::read_flow_cache(cache_dir, &key, n, w, h)? {
            Some((f, b)) => {
                (flow_fwd, flow_bwd) = (f, b);
            }
            None => {
                if !quiet {
                    eprintln!(
                        "computing optical flow for {n} frames ({w}x{h}); cached in {}",
                        cache_dir.display()
                    );
                }
                let (f, b) = nerf_flow::video_flows(&images, &params);
                nerf_flow::write_flow_cache(cache_dir, &key, &f, &b)?;
                (flow_fwd, flow_bwd) = (f, b);
            }
        }
    }
    let stride = nerf_flow::motion_stride(n);
    let report = nerf_flow::independent_motion(&cameras, &flow_fwd, motion_threshold_px, stride);
    let given_masks = given_motion_masks(&dataset, &frames, &given)?;
    let masks_given = given_masks.is_some();
    let moving = |m: &[f32]| -> Vec<bool> { m.iter().map(|&v| v > 0.5).collect() };
    let mut motion_masks: Vec<Vec<bool>> = match given_masks {
        Some(m) => m.into_iter().map(moving).collect(),
        None => nerf_flow::motion_masks(&cameras, &flow_fwd, &flow_bwd, masks, stride)
            .iter()
            .map(|m| moving(m))
            .collect(),
    };
    // Hard mining keeps the background pixels the flow test marks (taken before they are
    // unmasked): along a mover's silhouette they teach the dynamic field where the mover ends.
    let moving_pixels = motion_masks
        .iter()
        .map(|m| (0..m.len() as u32).filter(|&p| m[p as usize]).collect())
        .collect();
    if unmask_background {
        for (mask, &f) in motion_masks.iter_mut().zip(&frames) {
            if let Some(alpha) = &dataset.views[f].alpha {
                self::unmask_background(mask, alpha);
            }
        }
    }
    // Masks given with the video that mark anything say that something moves.
    let has_motion =
        report.has_independent_motion || (masks_given && motion_masks.iter().flatten().any(|&m| m));
    Ok(Video {
        motion_masks,
        moving_pixels,
        dataset,
        frames,
        times,
        flow_fwd,
        flow_bwd,
        disparity,
        camera_path,
        moving_fraction: Some(report.moving_fraction),
        has_motion,
        masks_given,
        masks_ignored: false,
    })
}

/// The motion masks given with the video (`motion_masks/<view name>.png`, NSFF's input, e.g.
/// from a segmentation network; values in [0, 1], moving above 0.5), one per training frame in
/// time order; `None` when none are given. Given for some frames only is an error: half the
/// video would be masked by another rule. Only checked here, not converted: a jumping camera
/// asks only whether masks are given.
fn given_motion_masks<'a>(
    dataset: &Dataset,
    frames: &[usize],
    given: &'a nerf_data::VideoPriors,
) -> Result<Option<Vec<&'a [f32]>>> {
    let masks: Vec<Option<&Vec<f32>>> = frames
        .iter()
        .map(|&f| given.motion_masks.get(f).and_then(|m| m.as_ref()))
        .collect();
    let count = masks.iter().filter(|m| m.is_some()).count();
    if count == 0 {
        return Ok(None);
    }
    if let Some(k) = masks.iter().position(|m| m.is_none()) {
        let name = &dataset.views[frames[k]].name;
        return Err(DataError::invalid(
            dataset.source.join("motion_masks").join(format!("{name}.png")),
            format!(
                "motion masks are given for {count} of the {} training frames but not for frame {k} ({name}); give one per training frame or none",
                frames.len()
            ),
        ));
    }
    Ok(Some(masks.into_iter().flatten().map(Vec::as_slice).collect()))
}

/// A jumping camera's video: no flows or motion masks (neighbouring frames are unrelated views),
/// and the motion is assumed (the flow that could rule it out means nothing here).
fn jumping(
    dataset: Dataset,
    frames: Vec<usize>,
    times: Vec<f32>,
    disparity: Vec<Option<Vec<f32>>>,
    camera_path: CameraPath,
) -> Video {
    let n = frames.len();
    let first = &dataset.views[frames[0]].image;
    let pixels = (first.width * first.height) as usize;
    Video {
        motion_masks: vec![vec![false; pixels]; n],
        moving_pixels: vec![Vec::new(); n],
        flow_fwd: vec![None; n],
        flow_bwd: vec![None; n],
        disparity,
        camera_path,
        moving_fraction: None,
        has_motion: true,
        masks_given: false,
        masks_ignored: false,
        dataset,
        frames,
        times,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unmask_background_clears_the_background_pixels_only() {
        let mut mask = vec![true, true, true, false];
        unmask_background(&mut mask, &[0.0, 0.5, 1.0, 0.0]);
        assert_eq!(mask, vec![false, true, true, false]);
    }

    /// A 6-frame `preset` video of `w`×`h` generated into `data`, with `nerf synth
    /// --motion-masks`'s masks when `masks`.
    fn generated(
        data: &Path,
        preset: nerf_synth::Preset,
        (w, h): (u32, u32),
        masks: bool,
    ) -> std::path::PathBuf {
        let mut synth = nerf_synth::SynthConfig::new(preset)
            .with_size(w, h)
            .with_views(6, 2);
        synth.motion_masks = masks;
        nerf_synth::generate(&synth, data).unwrap();
        data.to_path_buf()
    }

    /// Masks given with a video (`nerf synth --motion-masks`) are the ones training uses, hard
    /// mining included: every mover pixel (the generator's object ids) inside, every masked pixel
    /// within 2 steps of one. Given for some frames only, they are refused, naming the missing file.
    #[test]
    fn given_motion_masks_replace_the_flow_test_s() {
        let dir = std::env::temp_dir().join(format!("nsff-given-masks-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let data = generated(&dir.join("video"), nerf_synth::Preset::Dynamic, (32, 24), true);
        let scene = nerf_synth::Scene::load(&data).unwrap();
        let movers = scene.moving_objects();
        let rule = nerf_flow::MaskRule::either(0.35);
        let load = || nerf_data::load::load_video(&data, &nerf_data::LoadOptions::default()).unwrap();
        let video = prepare(load(), &dir.join("cache"), 1.0, rule, false, true).unwrap();
        assert!(video.masks_given && video.has_motion);
        let (w, h) = (32usize, 24usize);
        let mut mover_pixels = 0;
        for (k, &f) in video.frames.iter().enumerate() {
            let view = &video.dataset.views[f];
            let ids = scene
                .render(&view.camera, f64::from(view.time.unwrap()))
                .object_id;
            let on_mover = |p: usize| usize::try_from(ids[p]).is_ok_and(|i| movers.contains(&i));
            let mask = &video.motion_masks[k];
            for p in 0..w * h {
                let (x, y) = ((p % w) as i64, (p / w) as i64);
                let near_mover = (0..w * h)
                    .filter(|&q| on_mover(q))
                    .any(|q| ((q % w) as i64 - x).abs() + ((q / w) as i64 - y).abs() <= 2);
                if on_mover(p) {
                    mover_pixels += 1;
                    assert!(mask[p], "frame {k}: mover pixel {p} outside the given mask");
                }
                assert_eq!(mask[p], near_mover, "frame {k}, pixel {p}");
            }
            let mined: Vec<u32> = (0..(w * h) as u32).filter(|&p| mask[p as usize]).collect();
            assert_eq!(
                video.moving_pixels[k], mined,
                "hard mining follows the given masks"
            );
        }
        assert!(mover_pixels > 0, "the video has a mover in view");

        let missing = data.join("motion_masks").join("train").join("r_003.png");
        std::fs::remove_file(&missing).unwrap();
        let err = match prepare(load(), &dir.join("cache"), 1.0, rule, false, true) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("masks for five of six frames were accepted"),
        };
        assert!(err.contains("r_003.png") && err.contains("5 of the 6"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A jumping camera trains without motion masks (its settings were screened so): masks given
    /// with one are read, checked and reported as ignored, not used.
    #[test]
    fn a_jumping_camera_reports_its_given_masks_as_ignored() {
        let dir = std::env::temp_dir().join(format!("nsff-jumping-masks-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let rule = nerf_flow::MaskRule::either(0.35);
        let prepared = |masks: bool| {
            let data = dir.join(format!("jumping-{masks}"));
            let data = generated(&data, nerf_synth::Preset::JumpingMovers, (24, 24), masks);
            assert_eq!(data.join("motion_masks").exists(), masks);
            let dataset = nerf_data::load::load_video(&data, &nerf_data::LoadOptions::default()).unwrap();
            prepare(dataset, &dir.join("cache"), 1.0, rule, false, true).unwrap()
        };
        let (with, without) = (prepared(true), prepared(false));
        assert!(with.camera_path.is_jumping());
        assert!(with.masks_ignored && !with.masks_given);
        assert!(!without.masks_ignored && !without.masks_given);
        assert!(with.motion_masks.iter().flatten().all(|&m| !m));
        assert!(with.moving_pixels.iter().all(Vec::is_empty));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A run folder reused for another video of the same size computes that video's flows
    /// rather than reading the first one's (the cache is keyed to the frames).
    #[test]
    fn a_reused_flow_cache_follows_the_video() {
        let dir = std::env::temp_dir().join(format!("nsff-flow-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let load = |seed: u64| {
            let data = dir.join(format!("video{seed}"));
            let synth = nerf_synth::SynthConfig::new(nerf_synth::Preset::Dynamic)
                .with_seed(seed)
                .with_size(32, 24)
                .with_views(6, 2);
            nerf_synth::generate(&synth, &data).unwrap();
            nerf_data::load::load_video(&data, &nerf_data::LoadOptions::default()).unwrap()
        };
        let rule = nerf_flow::MaskRule::either(0.35);
        let prepare =
            |seed: u64, cache: &str| prepare(load(seed), &dir.join(cache), 1.0, rule, false, true).unwrap();
        let first = prepare(0, "shared");
        let second = prepare(1, "shared");
        let fresh = prepare(1, "fresh");
        assert_ne!(first.flow_fwd, fresh.flow_fwd, "the two videos' flows differ");
        assert_eq!(second.flow_fwd, fresh.flow_fwd);
        assert_eq!(second.flow_bwd, fresh.flow_bwd);
        // And the shared folder now holds the second video's flows, read back as they are.
        assert_eq!(prepare(1, "shared").flow_fwd, fresh.flow_fwd);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
