//! The error diagnosis of generated scenes: per-group statistics on hand-made images, and
//! moving-object masks of a small generated video (no training).

use std::path::PathBuf;

use nerf::diagnosis::{Diagnosis, GroupStats, Groups, load_scene, moving_mask, scene_view};
use nerf_data::LoadOptions;
use nerf_synth::{Preset, Split, SynthConfig, ViewKind};

/// Hand-made views whose squared errors are exact in f32: two in `off_path`, two in `mid_frame`.
#[test]
fn group_statistics_match_hand_computed_values() {
    let mut groups = Groups::default();
    // 2×2 RGB, truth 0.5 everywhere; pixel errors² 0.0625 (in), 0.0625, 0 (out), 0.5 (in).
    let truth = [0.5f32; 12];
    let render = [0.75, 0.5, 0.5, 0.5, 0.25, 0.5, 0.5, 0.5, 0.5, 1.0, 1.0, 0.5];
    groups.add(
        "off_path",
        &render,
        &truth,
        &[true, false, false, true],
        20.0,
        Some(0.5),
    );
    // 2×2 RGB, truth 0; errors² 0.015625 (in), 0.0625 three times (out).
    let truth = [0.0f32; 12];
    let render = [0.125, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 0.25];
    groups.add(
        "off_path",
        &render,
        &truth,
        &[true, false, false, false],
        30.0,
        Some(0.7),
    );
    // 1×2 RGB, exact render, all inside; then one without SSIM.
    let exact = [0.3f32; 6];
    groups.add("mid_frame", &exact, &exact, &[true, true], 40.0, Some(0.9));
    groups.add("mid_frame", &exact, &exact, &[true, true], 50.0, None);

    let stats = groups.finish();
    assert_eq!(
        stats.iter().map(|g| g.group.as_str()).collect::<Vec<_>>(),
        ["mid_frame", "off_path"]
    );
    let psnr = |mse: f64| -10.0 * mse.log10();
    let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-12, "{a} vs {b}");

    let off: &GroupStats = &stats[1];
    assert_eq!(off.views, 2);
    close(off.mean_psnr, 25.0);
    close(off.mean_ssim.expect("both views have SSIM"), 0.6);
    let (err_in, err_out) = (0.0625 + 0.5 + 0.015625, 0.0625 + 3.0 * 0.0625);
    close(
        off.error_share.expect("nonzero error"),
        err_in / (err_in + err_out),
    );
    close(off.area_share, 3.0 / 8.0);
    // Pooled over pixels × channels: 3 pixels inside, 5 outside, 3 channels each.
    close(off.psnr_inside.expect("pixels inside"), psnr(err_in / 9.0));
    close(off.psnr_outside.expect("pixels outside"), psnr(err_out / 15.0));

    let mid = &stats[0];
    assert_eq!(mid.views, 2);
    close(mid.mean_psnr, 45.0);
    assert_eq!(mid.mean_ssim, None, "one view without SSIM");
    assert_eq!(mid.error_share, None, "exact renders have no error to share");
    close(mid.area_share, 1.0);
    assert_eq!(mid.psnr_outside, None, "no pixel outside the masks");
    assert!(mid.psnr_inside.is_some_and(|p| p >= 100.0));
}

/// A temporary folder removed when dropped.
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[test]
fn masks_of_a_generated_video() {
    let dir = TempDir(std::env::temp_dir().join(format!("nerf-diagnosis-{}", std::process::id())));
    let cfg = SynthConfig::new(Preset::Dynamic)
        .with_size(32, 24)
        .with_views(4, 4);
    nerf_synth::generate(&cfg, &dir.0).unwrap();
    let scene = load_scene(&dir.0)
        .unwrap()
        .expect("scene.json written by the generator");
    assert!(load_scene(&std::env::temp_dir()).unwrap().is_none());
    let mover = *scene
        .moving_objects()
        .first()
        .expect("the dynamic preset has a mover");

    // Names carry their split folder; a bare stem shared by both splits is ambiguous.
    assert_eq!(
        scene_view(&scene, "test/r_000").map(|v| v.split),
        Some(Split::Test)
    );
    assert_eq!(
        scene_view(&scene, "train/r_000").map(|v| v.split),
        Some(Split::Train)
    );
    assert!(scene_view(&scene, "r_000").is_none());
    assert!(scene_view(&scene, "test/r_999").is_none());

    let ds = nerf_data::load::load_video(&dir.0, &LoadOptions::default()).unwrap();
    assert_eq!(ds.test.len(), 4);
    let mut seen = 0;
    let mut diagnosis = Diagnosis::new(&scene);
    for &v in &ds.test {
        let view = &ds.views[v];
        let sv = scene_view(&scene, &view.name).expect("every test view is in scene.json");
        assert!(matches!(sv.kind, ViewKind::OffPath | ViewKind::MidFrame));
        let mask = moving_mask(&scene, &view.camera, sv.time);
        let (w, h) = (view.image.width as usize, view.image.height as usize);
        assert_eq!(mask.len(), w * h);

        // The mover is in frame when its centre projects into the image and the ray through
        // that pixel hits it: that pixel must be in the mask.
        let centre = scene.objects[mover].to_world([0.0; 3], sv.time);
        if let Some((u, vv, _)) = view.camera.project(centre)
            && (0.0..w as f64).contains(&u)
            && (0.0..h as f64).contains(&vv)
        {
            let (i, j) = (u as u32, vv as u32);
            let dir_ij = view.camera.pixel_direction(i, j);
            let hit = scene.intersect(view.camera.pose.translation, dir_ij, sv.time);
            if hit.is_some_and(|h| h.object == mover) {
                assert!(
                    mask[j as usize * w + i as usize],
                    "{}: mover's pixel not masked",
                    view.name
                );
                seen += 1;
            }
        }

        // A render equal to the truth except inside the mask puts all the error there.
        let mut render = view.image.data.clone();
        for (p, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
            for c in &mut render[3 * p..3 * p + 3] {
                *c = if *c < 0.5 { *c + 0.5 } else { *c - 0.5 };
            }
        }
        let mut alone = Groups::default();
        alone.add("view", &render, &view.image.data, &mask, 0.0, None);
        let stats = &alone.finish()[0];
        if mask.contains(&true) {
            assert_eq!(stats.error_share, Some(1.0), "{}", view.name);
            assert_eq!(stats.psnr_outside.map(|p| p >= 100.0), Some(true));
        }
        let inside = mask.iter().filter(|m| **m).count();
        assert!((stats.area_share - inside as f64 / (w * h) as f64).abs() < 1e-12);
        diagnosis.add(
            view,
            &render,
            nerf_core::metrics::psnr(&render, &view.image.data),
            None,
        );
    }
    assert!(seen > 0, "the mover is in frame in no test view");
    let groups = diagnosis.finish().expect("test views described by scene.json");
    let names: Vec<&str> = groups.iter().map(|g| g.group.as_str()).collect();
    assert_eq!(names, ["mid_frame", "off_path"]);
    assert_eq!(groups.iter().map(|g| g.views).sum::<usize>(), 4);
    for g in &groups {
        assert_eq!(g.error_share, Some(1.0), "{}", g.group);
    }

    // Masks follow the dataset's resolution under --downscale.
    let opts = LoadOptions {
        downscale: 2,
        ..LoadOptions::default()
    };
    let half = nerf_data::load::load_video(&dir.0, &opts).unwrap();
    let view = &half.views[half.test[0]];
    let sv = scene_view(&scene, &view.name).unwrap();
    assert_eq!(moving_mask(&scene, &view.camera, sv.time).len(), 16 * 12);
}

/// eval.json of datasets without scene.json is unchanged: no `groups` key.
#[test]
fn eval_json_without_scene_has_no_groups() {
    let result = nerf::eval::EvalResult {
        split: "test".into(),
        step: 0,
        train_seconds: 0.0,
        views: Vec::new(),
        mean_psnr: 0.0,
        mean_ssim: None,
        samples_per_ray: 0.0,
        render_seconds: 0.0,
        groups: None,
    };
    let json = serde_json::to_value(&result).unwrap();
    assert!(json.get("groups").is_none());
    let back: nerf::eval::EvalResult = serde_json::from_value(json).unwrap();
    assert!(back.groups.is_none());
}
