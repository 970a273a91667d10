//! NSFF-style video folders: frames, times, folder choice, priors and bad priors.

use std::path::Path;

use nerf_data::npy::encode_npy;
use nerf_data::npz::write_zip;
use nerf_data::{Format, Image, LoadOptions, video};

mod common;
use common::TempDir;

fn err_text<T: std::fmt::Debug>(r: nerf_data::Result<T>) -> String {
    r.expect_err("expected an error").to_string()
}

/// Full-resolution frames are 16x12 (WxH); NSFF's training copies in images_8x6/ are 8x6.
const FULL: (u32, u32) = (16, 12);
const SMALL: (usize, usize) = (6, 8); // (H, W)

fn write_png(path: &Path, w: u32, h: u32, seed: u32) {
    let data = (0..w * h * 3)
        .map(|i| ((i * 5 + seed * 11) % 13) as f32 / 12.0)
        .collect();
    Image::from_data(w, h, 3, data).save_png(path).unwrap();
}

/// A `.npy` of uint8 values (NSFF's masks are bool/uint8), written by hand.
fn encode_u8_npy(shape: &[usize], data: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|s| s.to_string()).collect();
    let mut header = format!(
        "{{'descr': '|u1', 'fortran_order': False, 'shape': ({}), }}",
        dims.join(", ")
    );
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((header.len() as u16).to_le_bytes());
    out.extend(header.as_bytes());
    out.extend(data);
    out
}

/// Flow i -> j of frame i: dx = i + 0.25, dy = -j (per pixel index), mask = 1 on even pixels.
fn write_flow(path: &Path, (h, w): (usize, usize), i: usize) {
    let n = h * w;
    let flow: Vec<f64> = (0..n).flat_map(|p| [i as f64 + 0.25, -(p as f64)]).collect();
    let mask: Vec<u8> = (0..n).map(|p| u8::from(p % 2 == 0)).collect();
    let f = encode_npy(&[h, w, 2], &flow, true);
    let m = encode_u8_npy(&[h, w], &mask);
    std::fs::write(path, write_zip(&[("flow.npy", &f), ("mask.npy", &m)], true)).unwrap();
}

/// An NSFF-style folder of `n` frames: images/ at 16x12, images_8x6/, poses, and all priors.
fn synthetic_video(tag: &str, n: usize) -> TempDir {
    let tmp = TempDir::new(tag);
    let d = &tmp.0;
    for sub in ["images", "images_8x6", "disp", "flow_i1", "motion_masks"] {
        std::fs::create_dir_all(d.join(sub)).unwrap();
    }
    let mut flat = Vec::new();
    for i in 0..n {
        // OpenGL identity camera stored as [down, right, back], moving along x; hwf at full res.
        let x = 0.05 * i as f64;
        flat.extend([
            0.0, 1.0, 0.0, x, 12.0, -1.0, 0.0, 0.0, 0.0, 16.0, 0.0, 0.0, 1.0, 0.0, 20.0, 2.0, 12.0,
        ]);
        let name = format!("{i:05}");
        write_png(&d.join(format!("images/{name}.png")), FULL.0, FULL.1, i as u32);
        write_png(&d.join(format!("images_8x6/{name}.png")), 8, 6, i as u32);
        let disp: Vec<f64> = (0..SMALL.0 * SMALL.1).map(|p| (i * 100 + p) as f64).collect();
        std::fs::write(
            d.join(format!("disp/{name}.npy")),
            encode_npy(&[SMALL.0, SMALL.1], &disp, true),
        )
        .unwrap();
        if i + 1 < n {
            write_flow(&d.join(format!("flow_i1/{i:05}_fwd.npz")), SMALL, i);
        }
        if i > 0 {
            write_flow(&d.join(format!("flow_i1/{i:05}_bwd.npz")), SMALL, i);
        }
    }
    nerf_data::npy::write_npy(&d.join("poses_bounds.npy"), &[n, 17], &flat).unwrap();
    // A motion mask for frame 1 only.
    let mut m = Image::new(8, 6, 1);
    m.data[3] = 1.0;
    m.save_png(&d.join("motion_masks/00001.png")).unwrap();
    tmp
}

#[test]
fn video_loads_frames_times_and_priors() {
    let tmp = synthetic_video("ok", 4);
    // downscale 2 asks for 8x6, which NSFF's images_8x6/ provides.
    let ds = video::load(
        &tmp.0,
        &LoadOptions {
            downscale: 2,
            ..LoadOptions::default()
        },
    )
    .unwrap();
    assert_eq!(ds.format, Format::NsffVideo);
    assert_eq!(ds.views.len(), 4);
    let times: Vec<f32> = ds.views.iter().map(|v| v.time.unwrap()).collect();
    assert_eq!(times, vec![0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0]);
    assert_eq!(ds.train, vec![0, 1, 2, 3]);
    assert!(ds.test.is_empty() && ds.val.is_empty());
    assert_eq!((ds.views[0].image.width, ds.views[0].image.height), (8, 6));
    // Focal 20 at 16 px wide -> 10 at 8 px.
    assert!((ds.views[0].camera.intrinsics.fx - 10.0).abs() < 1e-12);
    // The frames are the images_8x6 copies, not a downscale of images/.
    let small = Image::load(&tmp.0.join("images_8x6/00002.png")).unwrap();
    assert_eq!(ds.views[2].image, small);
    assert!(ds.ndc.is_some());

    let pr = ds.priors.as_ref().expect("priors");
    let n = SMALL.0 * SMALL.1;
    for (i, d) in pr.disparity.iter().enumerate() {
        let d = d.as_ref().unwrap();
        assert_eq!(d.len(), n);
        assert_eq!(d[5], (i * 100 + 5) as f32);
    }
    let some = |v: &Vec<Option<nerf_data::FlowField>>| v.iter().map(Option::is_some).collect::<Vec<_>>();
    assert_eq!(some(&pr.flow_fwd), [true, true, true, false]);
    assert_eq!(some(&pr.flow_bwd), [false, true, true, true]);
    let f = pr.flow_fwd[2].as_ref().unwrap();
    assert_eq!((f.width, f.height), (8, 6));
    assert_eq!((f.flow[2 * 7], f.flow[2 * 7 + 1]), (2.25, -7.0));
    assert_eq!(&f.mask[..4], &[1.0, 0.0, 1.0, 0.0]);
    let masks: Vec<bool> = pr.motion_masks.iter().map(Option::is_some).collect();
    assert_eq!(masks, [false, true, false, false]);
    let m = pr.motion_masks[1].as_ref().unwrap();
    assert_eq!(m.len(), n);
    assert_eq!((m[3], m[4]), (1.0, 0.0));

    // At downscale 1 the NSFF training folder is still preferred (the priors live at its size), with a note.
    let ds = video::load(&tmp.0, &LoadOptions::default()).unwrap();
    assert_eq!((ds.views[0].image.width, ds.views[0].image.height), (8, 6));
    assert!(
        ds.notes.iter().any(|n| n.contains("images_8x6/")),
        "{:?}",
        ds.notes
    );

    // Every 2nd frame held out on request.
    let ds = video::load(
        &tmp.0,
        &LoadOptions {
            holdout: Some(2),
            ..LoadOptions::default()
        },
    )
    .unwrap();
    assert_eq!((ds.train.clone(), ds.test.clone()), (vec![1, 3], vec![0, 2]));
}

#[test]
fn video_without_priors_builds_frames_from_images() {
    let tmp = synthetic_video("nopriors", 3);
    for sub in ["images_8x6", "disp", "flow_i1", "motion_masks"] {
        std::fs::remove_dir_all(tmp.0.join(sub)).unwrap();
    }
    let ds = video::load(
        &tmp.0,
        &LoadOptions {
            downscale: 2,
            ..LoadOptions::default()
        },
    )
    .unwrap();
    assert!(ds.priors.is_none());
    assert_eq!((ds.views[0].image.width, ds.views[0].image.height), (8, 6));
    let full = Image::load(&tmp.0.join("images/00001.png")).unwrap();
    assert_eq!(ds.views[1].image, full.downscale(2));
    assert!(
        ds.notes
            .iter()
            .any(|n| n.contains("images_2/ not found") && n.contains("images/")),
        "{:?}",
        ds.notes
    );
}

#[test]
fn video_with_fewer_than_three_frames_is_an_error() {
    let tmp = synthetic_video("two", 2);
    let e = err_text(video::load(&tmp.0, &LoadOptions::default()));
    let name = tmp.0.file_name().unwrap().to_string_lossy().into_owned();
    assert!(e.contains(&name) && e.contains("at least 3 frames"), "{e}");
}

#[test]
fn video_priors_of_the_wrong_shape_name_file_and_shapes() {
    let tmp = synthetic_video("badflow", 4);
    write_flow(&tmp.0.join("flow_i1/00001_fwd.npz"), (3, 4), 1);
    let e = err_text(video::load(&tmp.0, &LoadOptions::default()));
    assert!(
        e.contains("flow_i1/00001_fwd.npz") && e.contains("flow is 3x4x2 but frames are 6x8"),
        "{e}"
    );

    let tmp = synthetic_video("baddisp", 4);
    std::fs::write(
        tmp.0.join("disp/00002.npy"),
        encode_npy(&[3, 4], &[0.5; 12], true),
    )
    .unwrap();
    let e = err_text(video::load(&tmp.0, &LoadOptions::default()));
    assert!(
        e.contains("disp/00002.npy") && e.contains("disparity is 3x4 but frames are 6x8"),
        "{e}"
    );

    let tmp = synthetic_video("nomask", 4);
    let f = encode_npy(&[6, 8, 2], &[0.0; 96], true);
    std::fs::write(
        tmp.0.join("flow_i1/00003_bwd.npz"),
        write_zip(&[("flow.npy", &f)], false),
    )
    .unwrap();
    let e = err_text(video::load(&tmp.0, &LoadOptions::default()));
    assert!(
        e.contains("flow_i1/00003_bwd.npz") && e.contains("no 'mask'"),
        "{e}"
    );

    let tmp = synthetic_video("badmask", 4);
    Image::new(4, 3, 1)
        .save_png(&tmp.0.join("motion_masks/00001.png"))
        .unwrap();
    let e = err_text(video::load(&tmp.0, &LoadOptions::default()));
    assert!(
        e.contains("motion_masks/00001.png") && e.contains("3x4 but frames are 6x8"),
        "{e}"
    );
}
