//! COLMAP and LLFF parsers: reproduction of the shipped beer `poses_bounds.npy`, text/binary
//! round trips, the LLFF pipeline on real data, camera conventions, and bad-input messages.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use nerf_data::colmap::{self, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint};
use nerf_data::math;
use nerf_data::{AxisConvention, Dataset, Format, Image, LoadOptions, Pose, llff};

mod common;
use common::TempDir;

fn beer() -> Option<PathBuf> {
    let dir = nerf_data::shared_data()?.join("llff/beer");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("skipping: {} not found", dir.display());
        None
    }
}

macro_rules! beer_or_skip {
    () => {
        match beer() {
            Some(d) => d,
            None => {
                eprintln!("skipping: shared data (../shared/data/llff/beer) is absent");
                return;
            }
        }
    };
}

fn err_text<T: std::fmt::Debug>(r: nerf_data::Result<T>) -> String {
    r.expect_err("expected an error").to_string()
}

fn row_parts(r: &[f64; 17]) -> (math::Mat3, math::Vec3) {
    (
        [[r[0], r[1], r[2]], [r[5], r[6], r[7]], [r[10], r[11], r[12]]],
        [r[3], r[8], r[13]],
    )
}

/// Rotation angle in degrees between two rotation matrices, from the Frobenius distance
/// (`|A - B|_F = 2 sqrt(2) sin(angle / 2)`), which stays accurate for tiny angles where acos does not.
fn angle_deg(a: &math::Mat3, b: &math::Mat3) -> f64 {
    let fro = a
        .iter()
        .flatten()
        .zip(b.iter().flatten())
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt();
    (2.0 * (fro / (2.0 * 2f64.sqrt())).min(1.0).asin()).to_degrees()
}

#[test]
fn colmap_bin_reproduces_beer_poses_bounds() {
    let dir = beer_or_skip!();
    let model_dir = colmap::find_model_dir(&dir).unwrap();
    assert_eq!(model_dir, dir.join("sparse/0"));
    assert_eq!(colmap::find_model_dir(&model_dir).unwrap(), model_dir);
    let model = colmap::read_model(&model_dir).unwrap();
    assert_eq!(model.images.len(), 71);
    assert_eq!(model.cameras.len(), 71);
    let pb = colmap::poses_bounds(&model, &model_dir).unwrap();
    let shipped = llff::read_poses_bounds(&dir.join("poses_bounds.npy")).unwrap();
    assert_eq!(pb.rows.len(), shipped.len());
    assert!(
        pb.names.windows(2).all(|w| w[0] < w[1]),
        "rows are sorted by image name"
    );

    let (mut max_rot, mut max_t, mut max_b, mut max_hwf) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (a, b) in pb.rows.iter().zip(&shipped) {
        let ((ra, ta), (rb, tb)) = (row_parts(a), row_parts(b));
        max_rot = max_rot.max(angle_deg(&ra, &rb));
        max_t = max_t.max(math::norm(math::sub(ta, tb)) / math::norm(tb));
        for k in [15, 16] {
            max_b = max_b.max((a[k] - b[k]).abs() / b[k]);
        }
        for k in [4, 9, 14] {
            max_hwf = max_hwf.max((a[k] - b[k]).abs());
        }
    }
    eprintln!(
        "beer imgs2poses vs shipped poses_bounds.npy: max rotation {max_rot:.3e} deg, translation {max_t:.3e} \
         rel, bounds {max_b:.3e} rel, hwf {max_hwf:.3e}"
    );
    assert!(max_rot < 0.01, "rotation error {max_rot} deg");
    assert!(max_t < 1e-3, "translation error {max_t}");
    assert!(max_b < 1e-3, "bounds error {max_b}");
    assert!(max_hwf < 1e-9, "hwf error {max_hwf}");

    // The writer produces an N x 17 <f8 array that reads back bit-identical.
    let tmp = TempDir::new("pbwrite");
    let path = tmp.0.join("poses_bounds.npy");
    pb.write(&path).unwrap();
    assert_eq!(llff::read_poses_bounds(&path).unwrap(), pb.rows);
}

#[test]
fn colmap_text_and_binary_round_trip_on_beer() {
    let dir = beer_or_skip!();
    let model_dir = dir.join("sparse/0");
    let bin = colmap::read_model(&model_dir).unwrap();

    let txt_dir = TempDir::new("txt");
    colmap::write_text(&bin, &txt_dir.0).unwrap();
    assert!(!txt_dir.0.join("cameras.bin").exists());
    let txt = colmap::read_model(&txt_dir.0).unwrap();
    assert!(txt == bin, "the text model reads back equal to the binary one");

    // Writing binary reproduces COLMAP's files byte for byte.
    let bin_dir = TempDir::new("bin");
    colmap::write_binary(&bin, &bin_dir.0).unwrap();
    for f in ["cameras.bin", "images.bin", "points3D.bin"] {
        let a = std::fs::read(model_dir.join(f)).unwrap();
        let b = std::fs::read(bin_dir.0.join(f)).unwrap();
        assert!(a == b, "{f} differs after a read/write round trip");
    }
}

/// A small hand-written text model: comments, an image with no 2-D points (empty line), names
/// with a space, a PINHOLE and an OPENCV camera.
#[test]
fn colmap_text_with_empty_point_lines_matches_binary() {
    let tmp = TempDir::new("handtxt");
    std::fs::write(
        tmp.0.join("cameras.txt"),
        "# Camera list\n# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n# Number of cameras: 2\n\
         1 PINHOLE 640 480 500 510 320 240\n2 OPENCV 64 48 50 50 32 24 0.1 -0.01 0.001 0.002\n",
    )
    .unwrap();
    std::fs::write(
        tmp.0.join("images.txt"),
        "# Image list with two lines of data per image:\n\
         #   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n\
         #   POINTS2D[] as (X, Y, POINT3D_ID)\n\
         # Number of images: 3\n\
         5 1 0 0 0 0.5 -0.25 2 1 frame b.png\n\
         \n\
         2 0.9238795325112867 0 0.3826834323650898 0 1 2 3 2 a.png\n\
         10.5 20.25 7 11 12 -1\n\
         9 1 0 0 0 0 0 0 1 c.png\n\
         \n",
    )
    .unwrap();
    std::fs::write(
        tmp.0.join("points3D.txt"),
        "# 3D point list\n7 0.1 0.2 5.0 255 128 0 0.5 2 0\n8 1 2 3 1 2 3 0.25\n",
    )
    .unwrap();
    let txt = colmap::read_model(&tmp.0).unwrap();
    let want = ColmapModel {
        cameras: vec![
            ColmapCamera {
                id: 1,
                model_id: 1,
                width: 640,
                height: 480,
                params: vec![500.0, 510.0, 320.0, 240.0],
            },
            ColmapCamera {
                id: 2,
                model_id: 4,
                width: 64,
                height: 48,
                params: vec![50.0, 50.0, 32.0, 24.0, 0.1, -0.01, 0.001, 0.002],
            },
        ],
        images: vec![
            ColmapImage {
                id: 5,
                qvec: [1.0, 0.0, 0.0, 0.0],
                tvec: [0.5, -0.25, 2.0],
                camera_id: 1,
                name: "frame b.png".into(),
                points2d: vec![],
            },
            ColmapImage {
                id: 2,
                qvec: [0.9238795325112867, 0.0, 0.3826834323650898, 0.0],
                tvec: [1.0, 2.0, 3.0],
                camera_id: 2,
                name: "a.png".into(),
                points2d: vec![([10.5, 20.25], 7), ([11.0, 12.0], -1)],
            },
            ColmapImage {
                id: 9,
                qvec: [1.0, 0.0, 0.0, 0.0],
                tvec: [0.0; 3],
                camera_id: 1,
                name: "c.png".into(),
                points2d: vec![],
            },
        ],
        points: vec![
            ColmapPoint {
                id: 7,
                xyz: [0.1, 0.2, 5.0],
                rgb: [255, 128, 0],
                error: 0.5,
                track: vec![(2, 0)],
            },
            ColmapPoint {
                id: 8,
                xyz: [1.0, 2.0, 3.0],
                rgb: [1, 2, 3],
                error: 0.25,
                track: vec![],
            },
        ],
    };
    assert_eq!(txt, want);

    // The same model through the binary writer and reader.
    let bdir = TempDir::new("handbin");
    colmap::write_binary(&txt, &bdir.0).unwrap();
    assert_eq!(colmap::read_model(&bdir.0).unwrap(), txt);
    // And through our text writer: the empty observation lines survive.
    let tdir = TempDir::new("handtxt2");
    colmap::write_text(&txt, &tdir.0).unwrap();
    assert_eq!(colmap::read_model(&tdir.0).unwrap(), txt);
}

// ---------------------------------------------------------------------------------------------
// The beer capture through the LLFF pipeline (71 full-resolution JPEGs, loaded once).

fn beer_x8() -> Option<&'static Dataset> {
    static DS: OnceLock<Option<Dataset>> = OnceLock::new();
    DS.get_or_init(|| {
        let dir = beer()?;
        // NDC forced: these tests check nerf-pytorch's NDC pipeline on real rows.
        let opts = LoadOptions {
            downscale: 8,
            ndc: nerf_data::NdcMode::On,
            ..LoadOptions::default()
        };
        let t = std::time::Instant::now();
        let ds = llff::load(&dir, &opts).unwrap();
        eprintln!("loaded beer at 1/8 in {:.2}s", t.elapsed().as_secs_f64());
        Some(ds)
    })
    .as_ref()
}

#[test]
fn beer_downscale_8_builds_images_and_holds_out_every_8th() {
    let Some(ds) = beer_x8() else {
        eprintln!("skipping: shared data absent");
        return;
    };
    let dir = beer().unwrap();
    assert_eq!(ds.format, Format::Llff);
    assert_eq!(ds.views.len(), 71);
    for v in &ds.views {
        assert_eq!((v.image.width, v.image.height), (90, 160));
    }
    assert!(
        ds.notes
            .iter()
            .any(|n| n.contains("images_8/ has 29 images for 71 poses") && n.contains("images/")),
        "notes: {:?}",
        ds.notes
    );
    assert_eq!(ds.test, (0..71).step_by(8).collect::<Vec<_>>());
    assert_eq!(ds.test, vec![0, 8, 16, 24, 32, 40, 48, 56, 64]);
    assert_eq!(ds.val, ds.test);
    assert_eq!(ds.train.len(), 62);
    assert!(ds.train.iter().all(|i| i % 8 != 0));
    // Rows pair with the sorted file names.
    let names: Vec<String> = (0..71).map(|i| format!("{i:04}")).collect();
    assert_eq!(ds.views.iter().map(|v| v.name.clone()).collect::<Vec<_>>(), names);
    // Intrinsics: the focal scaled by 90/720, centred principal point.
    let k = ds.views[0].camera.intrinsics;
    assert!((k.fx - 1105.13 * 90.0 / 720.0).abs() < 0.01, "fx {}", k.fx);
    assert_eq!((k.cx, k.cy), (45.0, 80.0));
    // NDC setup: min bound 1/0.75 after rescaling.
    let ndc = ds.ndc.expect("NDC by default");
    assert_eq!((ndc.width, ndc.height, ndc.near), (90.0, 160.0, 1.0));
    assert_eq!((ds.near, ds.far), (0.0, 1.0));
    assert!(
        (ds.depth_bounds[0] - 1.0 / 0.75).abs() < 1e-5,
        "{:?}",
        ds.depth_bounds
    );
    // Recentred: the average pose is the identity.
    let poses: Vec<Pose> = ds.views.iter().map(|v| v.camera.pose).collect();
    let avg = llff::average_pose(&poses);
    for r in 0..3 {
        for c in 0..3 {
            assert!((avg.rotation[r][c] - f64::from(u8::from(r == c))).abs() < 1e-9);
        }
        assert!(avg.translation[r].abs() < 1e-9);
    }

    // The built images look like the shipped 8x thumbnails of the same name, not of another.
    let diff = |img: &Image, path: &Path| {
        let t = Image::load(path).unwrap();
        assert_eq!((t.width, t.height), (img.width, img.height));
        img.data
            .iter()
            .zip(&t.data)
            .map(|(a, b)| (a - b).abs())
            .sum::<f32>()
            / img.data.len() as f32
    };
    for k in [0usize, 13, 28] {
        let same = diff(&ds.views[k].image, &dir.join(format!("images_8/{k:04}.jpg")));
        let other = diff(
            &ds.views[k].image,
            &dir.join(format!("images_8/{:04}.jpg", (k + 14) % 29)),
        );
        assert!(
            same < 0.03 && same < other / 2.0,
            "view {k}: same-name diff {same}, other {other}"
        );
    }

    // Spiral path: every camera looks at the focus point on the average camera's axis (the
    // average pose is the identity here), at NeRF's focus depth, and the spiral spans the 90th
    // percentile of |x| of the camera centres.
    let path = llff::spiral_path(ds, 120);
    assert_eq!(path.len(), 120);
    let [near, far] = ds.depth_bounds.map(f64::from);
    let focus = 1.0 / (0.25 / (0.9 * near) + 0.75 / (5.0 * far));
    let target = [0.0, 0.0, -focus];
    for p in &path {
        assert!(p.is_finite());
        let back = math::column(&p.rotation, 2);
        let to_cam = math::normalize(math::sub(p.translation, target));
        assert!(
            math::norm(math::cross(back, to_cam)) < 1e-9,
            "spiral camera does not face the focus point"
        );
        assert!(
            math::column(&p.rotation, 1)[1] > 0.5,
            "spiral cameras stay upright"
        );
    }
    let xs: Vec<f64> = poses.iter().map(|p| p.translation[0].abs()).collect();
    let rx = math::percentile(&xs, 90.0);
    assert!(
        (path[0].translation[0] - rx).abs() < 1e-9,
        "{} vs {rx}",
        path[0].translation[0]
    );
    assert!(
        (path[30].translation[0] + rx).abs() < 1e-9,
        "half a turn later the camera is at -rx"
    );
}

#[test]
fn beer_rays_project_back_to_their_pixels() {
    let Some(ds) = beer_x8() else {
        eprintln!("skipping: shared data absent");
        return;
    };
    let ndc = ds.ndc.unwrap();
    let mut worst = 0.0f64;
    for view in [0usize, 5, 70] {
        let cam = ds.views[view].camera;
        let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
        let pixels = [0, w - 1, (h / 2) * w + w / 2, h * w - 1, 37 * w + 11];
        // Euclidean rays: t is camera depth.
        let rays = nerf_data::rays::pixel_rays(&cam, pixels);
        // NDC rays.
        let nrays = ds.rays_for(&cam, pixels);
        for (k, &p) in pixels.iter().enumerate() {
            let want = ((p % w) as f64 + 0.5, (p / w) as f64 + 0.5);
            let (o, d) = (rays.origin(k).map(f64::from), rays.direction(k).map(f64::from));
            for s in [1.5, 3.0, 20.0] {
                let x = [0, 1, 2].map(|a| o[a] + s * d[a]);
                let (u, v, depth) = cam.project(x).unwrap();
                worst = worst.max((u - want.0).abs()).max((v - want.1).abs());
                assert!((depth - s).abs() < 1e-4 * s, "depth {depth} for t {s}");
            }
            let (o, d) = (nrays.origin(k).map(f64::from), nrays.direction(k).map(f64::from));
            for t in [0.1, 0.5, 0.9] {
                let x = ndc.to_world([0, 1, 2].map(|a| o[a] + t * d[a]));
                let (u, v, _) = cam.project(x).unwrap();
                worst = worst.max((u - want.0).abs()).max((v - want.1).abs());
            }
        }
    }
    eprintln!("worst ray -> point -> pixel error: {worst:.2e} px");
    assert!(worst < 1e-4, "worst round-trip error {worst} px");
}

/// COLMAP's own 2-D observations land where the loaded cameras project their 3-D points: this
/// pins down the whole chain of axis conventions (OpenCV -> LLFF stored -> OpenGL), the rescale,
/// the recentring and the pixel-centre convention.
#[test]
fn beer_colmap_points_project_onto_their_observations() {
    let Some(ds) = beer_x8() else {
        eprintln!("skipping: shared data absent");
        return;
    };
    let dir = beer().unwrap();
    let model = colmap::read_model(&dir.join("sparse/0")).unwrap();
    let rows = llff::read_poses_bounds(&dir.join("poses_bounds.npy")).unwrap();
    let sc = 1.0 / (rows.iter().map(|r| r[15]).fold(f64::INFINITY, f64::min) * 0.75);
    let mut images: Vec<&ColmapImage> = model.images.iter().collect();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    // COLMAP camera k as an OpenGL c2w in COLMAP's world.
    let gl = |im: &ColmapImage| {
        let rt = math::transpose(&im.rotation());
        let c = im.center();
        let m = [0, 1, 2].map(|r| [rt[r][0], rt[r][1], rt[r][2], c[r]]);
        Pose::from_c2w(m, AxisConvention::OpenCv)
    };
    // World transform of the pipeline, recovered from view 0: X_ds = A (sc X).
    let c0 = gl(images[0]);
    let p0 = ds.views[0].camera.pose;
    let a_rot = math::mat_mul(&p0.rotation, &math::transpose(&c0.rotation));
    let a_t = math::sub(
        p0.translation,
        math::mat_vec(&a_rot, math::scale(c0.translation, sc)),
    );
    let cam0 = &model.cameras[0];
    let points: std::collections::HashMap<u64, [f64; 3]> =
        model.points.iter().map(|p| (p.id, p.xyz)).collect();
    let mut errors = Vec::new();
    for (k, im) in images.iter().enumerate() {
        let cam = model.cameras.iter().find(|c| c.id == im.camera_id).unwrap();
        // LLFF keeps only the first camera's focal and no distortion: compare where that holds.
        if (cam.params[0] / cam0.params[0] - 1.0).abs() > 0.005 {
            continue;
        }
        for ([x, y], id) in &im.points2d {
            let Some(xyz) = (*id >= 0).then(|| points.get(&(*id as u64))).flatten() else {
                continue;
            };
            if ((x - 360.0).powi(2) + (y - 640.0).powi(2)).sqrt() > 150.0 {
                continue;
            }
            let xw = math::add(math::mat_vec(&a_rot, math::scale(*xyz, sc)), a_t);
            let (u, v, _) = ds.views[k].camera.project(xw).unwrap();
            errors.push(((u - x / 8.0).powi(2) + (v - y / 8.0).powi(2)).sqrt());
        }
    }
    errors.sort_by(f64::total_cmp);
    assert!(errors.len() > 100, "only {} observations compared", errors.len());
    let median = errors[errors.len() / 2];
    eprintln!(
        "COLMAP observations vs loaded cameras (1/8 res): {} points, median {median:.3} px",
        errors.len()
    );
    assert!(
        median < 0.3,
        "median reprojection error {median} px at 1/8 resolution"
    );
}

// ---------------------------------------------------------------------------------------------
// Synthetic captures: tiny PNGs and forward-facing poses.

/// A stored LLFF row: camera at `centre` looking down world -z (OpenGL R = I), hwf, bounds.
fn llff_row(centre: [f64; 3], hwf: [f64; 3], bounds: [f64; 2]) -> [f64; 17] {
    // Stored columns [down, right, back] of an OpenGL identity camera.
    let (down, right, back) = ([0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
    let mut r = [0.0; 17];
    for a in 0..3 {
        r[a * 5..a * 5 + 5].copy_from_slice(&[down[a], right[a], back[a], centre[a], hwf[a]]);
    }
    r[15] = bounds[0];
    r[16] = bounds[1];
    r
}

fn write_rows(path: &Path, rows: &[[f64; 17]]) {
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    nerf_data::npy::write_npy(path, &[rows.len(), 17], &flat).unwrap();
}

fn write_png(path: &Path, w: u32, h: u32, seed: u32) {
    let data = (0..w * h * 3)
        .map(|i| ((i * 7 + seed * 13) % 17) as f32 / 16.0)
        .collect();
    Image::from_data(w, h, 3, data).save_png(path).unwrap();
}

/// An LLFF folder of `n` 8x6 PNGs with matching rows (hwf 6x8, f = 10).
fn synthetic_llff(tag: &str, n: usize) -> TempDir {
    let tmp = TempDir::new(tag);
    std::fs::create_dir_all(tmp.0.join("images")).unwrap();
    let rows: Vec<[f64; 17]> = (0..n)
        .map(|i| llff_row([0.1 * i as f64, 0.0, 0.0], [6.0, 8.0, 10.0], [2.0, 10.0]))
        .collect();
    write_rows(&tmp.0.join("poses_bounds.npy"), &rows);
    for i in 0..n {
        write_png(&tmp.0.join(format!("images/{i:03}.png")), 8, 6, i as u32);
    }
    tmp
}

#[test]
fn synthetic_llff_loads_with_and_without_ndc() {
    let tmp = synthetic_llff("ok", 10);
    let ds = llff::load(&tmp.0, &LoadOptions::default()).unwrap();
    assert_eq!(ds.views.len(), 10);
    assert_eq!(ds.test, vec![0, 8]);
    assert_eq!(ds.kind, nerf_data::SceneKind::ForwardFacing);
    assert!(
        ds.ndc.is_some(),
        "parallel cameras are forward-facing: auto picks NDC"
    );
    // Bounds 2..10 rescaled by 1/(2 * 0.75).
    assert!((ds.depth_bounds[0] - 4.0 / 3.0).abs() < 1e-6 && (ds.depth_bounds[1] - 20.0 / 3.0).abs() < 1e-5);
    // Cameras along world x, spaced 0.1 * sc after rescale; already facing -z, so recentring only shifts.
    let c1 = ds.views[1].camera.pose.translation;
    let c0 = ds.views[0].camera.pose.translation;
    assert!((math::norm(math::sub(c1, c0)) - 0.1 / 1.5).abs() < 1e-12);

    let opts = LoadOptions {
        ndc: nerf_data::NdcMode::Off,
        holdout: Some(0),
        ..LoadOptions::default()
    };
    let ds = llff::load(&tmp.0, &opts).unwrap();
    assert!(ds.ndc.is_none());
    assert!(ds.test.is_empty() && ds.train.len() == 10);
    assert!((ds.near - 0.9 * 4.0 / 3.0).abs() < 1e-6 && (ds.far - 20.0 / 3.0).abs() < 1e-5);
    // The box holds every camera and the far-plane frustum corners.
    for v in &ds.views {
        let far_pt = v
            .camera
            .pose
            .to_world([-4.0 / 10.0 * 20.0 / 3.0, 0.0, -20.0 / 3.0]);
        for p in [v.camera.pose.translation, far_pt] {
            for ((x, lo), hi) in p.iter().zip(ds.aabb[0]).zip(ds.aabb[1]) {
                assert!(
                    *x as f32 >= lo - 1e-5 && *x as f32 <= hi + 1e-5,
                    "{p:?} outside {:?}",
                    ds.aabb
                );
            }
        }
    }
}

#[test]
fn bad_llff_inputs_name_the_file_and_the_problem() {
    // Missing folder.
    let missing = std::env::temp_dir().join("nerf-data-llff-does-not-exist");
    let e = err_text(llff::load(&missing, &LoadOptions::default()));
    assert!(
        e.contains("nerf-data-llff-does-not-exist") && e.contains("not found"),
        "{e}"
    );

    // Missing poses_bounds.npy.
    let tmp = synthetic_llff("nopb", 3);
    std::fs::remove_file(tmp.0.join("poses_bounds.npy")).unwrap();
    let e = err_text(llff::load(&tmp.0, &LoadOptions::default()));
    assert!(e.contains("poses_bounds.npy") && e.contains("not found"), "{e}");

    // Truncated poses_bounds.npy.
    let tmp = synthetic_llff("trunc", 3);
    let path = tmp.0.join("poses_bounds.npy");
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() - 20]).unwrap();
    let e = err_text(llff::load(&tmp.0, &LoadOptions::default()));
    assert!(e.contains("poses_bounds.npy") && e.contains("truncated"), "{e}");

    // Wrong shape (N x 15).
    nerf_data::npy::write_npy(&path, &[3, 15], &[1.0; 45]).unwrap();
    let e = err_text(llff::load(&tmp.0, &LoadOptions::default()));
    assert!(
        e.contains("poses_bounds.npy") && e.contains("[3, 15]") && e.contains("(N, 17)"),
        "{e}"
    );

    // NaN in a pose: the message names the row.
    let mut rows: Vec<[f64; 17]> = (0..3)
        .map(|i| llff_row([i as f64, 0.0, 0.0], [6.0, 8.0, 10.0], [2.0, 9.0]))
        .collect();
    rows[2][8] = f64::NAN;
    write_rows(&path, &rows);
    let e = err_text(llff::load(&tmp.0, &LoadOptions::default()));
    assert!(
        e.contains("poses_bounds.npy") && e.contains("row 2") && e.contains("NaN"),
        "{e}"
    );

    // Non-positive focal.
    rows[2][8] = 0.0;
    rows[1][14] = -3.0;
    write_rows(&path, &rows);
    let e = err_text(llff::load(&tmp.0, &LoadOptions::default()));
    assert!(
        e.contains("poses_bounds.npy") && e.contains("row 1") && e.contains("focal"),
        "{e}"
    );

    // Non-positive bound.
    rows[1][14] = 10.0;
    rows[0][15] = 0.0;
    write_rows(&path, &rows);
    let e = err_text(llff::load(&tmp.0, &LoadOptions::default()));
    assert!(
        e.contains("poses_bounds.npy") && e.contains("row 0") && e.contains("bounds"),
        "{e}"
    );

    // Image count differs from the pose count.
    rows[0][15] = 2.0;
    rows.push(llff_row([0.5, 0.0, 0.0], [6.0, 8.0, 10.0], [2.0, 9.0]));
    write_rows(&path, &rows);
    let e = err_text(llff::load(&tmp.0, &LoadOptions::default()));
    assert!(e.contains("images") && e.contains("3 images for 4 poses"), "{e}");

    // An image of the wrong size is named.
    rows.pop();
    write_rows(&path, &rows);
    write_png(&tmp.0.join("images/001.png"), 9, 7, 0);
    let e = err_text(llff::load(&tmp.0, &LoadOptions::default()));
    assert!(e.contains("001.png") && e.contains("9x7"), "{e}");
    write_png(&tmp.0.join("images/001.png"), 8, 6, 0);
    assert!(llff::load(&tmp.0, &LoadOptions::default()).is_ok());
}

// ---------------------------------------------------------------------------------------------
// COLMAP-only captures and corrupt binaries.

/// A synthetic COLMAP capture: four registered images with non-contiguous ids listed out of
/// name order, one unregistered extra image in images/, points 4..8 in front of the cameras.
fn synthetic_colmap(tag: &str) -> TempDir {
    let tmp = TempDir::new(tag);
    let names = ["c.png", "a.png", "d.png", "b.png"];
    let ids = [10u32, 3, 7, 5];
    let images: Vec<ColmapImage> = (0..4)
        .map(|k| {
            // A small rotation about y, and the centre along x.
            let half = 0.02 * k as f64;
            let qvec = [half.cos(), 0.0, half.sin(), 0.0];
            let r = math::quat_to_mat(qvec);
            let centre = [0.2 * k as f64, 0.05, 0.0];
            let tvec = math::scale(math::mat_vec(&r, centre), -1.0);
            ColmapImage {
                id: ids[k],
                qvec,
                tvec,
                camera_id: 1,
                name: names[k].into(),
                points2d: vec![],
            }
        })
        .collect();
    let points: Vec<ColmapPoint> = (0..50)
        .map(|i| ColmapPoint {
            id: i + 1,
            xyz: [
                (i % 5) as f64 * 0.3 - 0.6,
                (i / 5 % 5) as f64 * 0.2 - 0.4,
                4.0 + (i % 7) as f64 * 0.6,
            ],
            rgb: [0; 3],
            error: 0.1,
            track: ids.iter().map(|&id| (id, 0)).collect(),
        })
        .collect();
    let model = ColmapModel {
        cameras: vec![ColmapCamera {
            id: 1,
            model_id: 0,
            width: 8,
            height: 6,
            params: vec![10.0, 4.0, 3.0],
        }],
        images,
        points,
    };
    std::fs::create_dir_all(tmp.0.join("sparse/0")).unwrap();
    colmap::write_binary(&model, &tmp.0.join("sparse/0")).unwrap();
    std::fs::create_dir_all(tmp.0.join("images")).unwrap();
    for (i, n) in ["a.png", "b.png", "c.png", "d.png", "e_unregistered.png"]
        .iter()
        .enumerate()
    {
        write_png(&tmp.0.join("images").join(n), 8, 6, i as u32);
    }
    tmp
}

#[test]
fn colmap_only_capture_loads_through_the_llff_pipeline() {
    let tmp = synthetic_colmap("colmaponly");
    let ds = colmap::load(&tmp.0, &LoadOptions::default()).unwrap();
    assert_eq!(ds.format, Format::Colmap);
    let names: Vec<&str> = ds.views.iter().map(|v| v.name.as_str()).collect();
    assert_eq!(
        names,
        ["a", "b", "c", "d"],
        "registered images only, sorted by name"
    );
    assert_eq!(ds.test, vec![0]);
    // The same rows through poses_bounds.npy give the same poses; there, images/ must match exactly.
    let model_dir = tmp.0.join("sparse/0");
    let pb = colmap::poses_bounds(&colmap::read_model(&model_dir).unwrap(), &model_dir).unwrap();
    pb.write(&tmp.0.join("poses_bounds.npy")).unwrap();
    let e = err_text(llff::load(&tmp.0, &LoadOptions::default()));
    assert!(e.contains("images") && e.contains("5 images for 4 poses"), "{e}");
    std::fs::remove_file(tmp.0.join("images/e_unregistered.png")).unwrap();
    let ll = llff::load(&tmp.0, &LoadOptions::default()).unwrap();
    for (a, b) in ll.views.iter().zip(&ds.views) {
        assert_eq!(a.camera, b.camera);
        assert_eq!(a.image, b.image);
    }
    // Image "a" (id 3) was the second camera: centre x = 0.2 before the pipeline's transform.
    let pose_a = pb.rows[0];
    assert!((pose_a[3] - 0.2).abs() < 1e-12, "{:?}", &pose_a[..15]);
}

fn copy_beer_model(tag: &str) -> Option<TempDir> {
    let src = beer()?.join("sparse/0");
    let tmp = TempDir::new(tag);
    for f in ["cameras.bin", "images.bin", "points3D.bin"] {
        std::fs::copy(src.join(f), tmp.0.join(f)).unwrap();
    }
    Some(tmp)
}

/// The byte offset a truncation error reports.
fn reported_offset(msg: &str) -> usize {
    let rest = msg
        .split("truncated at byte ")
        .nth(1)
        .unwrap_or_else(|| panic!("no offset in: {msg}"));
    rest.split(|c: char| !c.is_ascii_digit())
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

#[test]
fn truncated_colmap_binaries_report_file_and_byte_offset() {
    let Some(tmp) = copy_beer_model("truncbin") else {
        eprintln!("skipping: shared data absent");
        return;
    };
    // cameras.bin: 8-byte count, then 56-byte SIMPLE_RADIAL records (id, model, w, h, 4 params).
    // Cut at 100: camera 1 starts at 64, its params at 88, 96, 104, so param 1 at 96 runs out.
    let cams = std::fs::read(tmp.0.join("cameras.bin")).unwrap();
    std::fs::write(tmp.0.join("cameras.bin"), &cams[..100]).unwrap();
    let e = err_text(colmap::read_model(&tmp.0));
    assert!(
        e.contains("cameras.bin") && e.contains("truncated at byte 96") && e.contains("camera record 1"),
        "{e}"
    );
    std::fs::write(tmp.0.join("cameras.bin"), &cams[..5]).unwrap();
    let e = err_text(colmap::read_model(&tmp.0));
    assert!(
        e.contains("cameras.bin") && e.contains("truncated at byte 0"),
        "{e}"
    );
    std::fs::write(tmp.0.join("cameras.bin"), &cams).unwrap();

    for (file, record) in [("images.bin", 24usize), ("points3D.bin", 8)] {
        let full = std::fs::read(tmp.0.join(file)).unwrap();
        for cut in [9, 60, 71, 1000, 123_457, full.len() - 1] {
            std::fs::write(tmp.0.join(file), &full[..cut]).unwrap();
            let e = err_text(colmap::read_model(&tmp.0));
            assert!(e.contains(file) && e.contains("truncated at byte"), "{e}");
            let at = reported_offset(&e);
            // The offset is where the incomplete field (or 2-D point / track entry) starts.
            assert!(at <= cut && at + record.max(8) > cut, "{file} cut at {cut}: {e}");
        }
        std::fs::write(tmp.0.join(file), &full).unwrap();
    }
    assert!(colmap::read_model(&tmp.0).is_ok());
}

#[test]
fn invalid_colmap_model_id_is_rejected_with_its_offset() {
    let Some(tmp) = copy_beer_model("model99") else {
        eprintln!("skipping: shared data absent");
        return;
    };
    let mut cams = std::fs::read(tmp.0.join("cameras.bin")).unwrap();
    // Camera record 1 starts at 8 + 56; its model id follows the 4-byte camera id.
    cams[68..72].copy_from_slice(&99i32.to_le_bytes());
    std::fs::write(tmp.0.join("cameras.bin"), &cams).unwrap();
    let e = err_text(colmap::read_model(&tmp.0));
    assert!(
        e.contains("cameras.bin") && e.contains("byte 68") && e.contains("model id 99"),
        "{e}"
    );

    // The same in text form names the line.
    let t = TempDir::new("model99txt");
    std::fs::write(t.0.join("cameras.txt"), "# c\n1 99 10 10 1 2 3\n").unwrap();
    std::fs::write(t.0.join("images.txt"), "").unwrap();
    std::fs::write(t.0.join("points3D.txt"), "").unwrap();
    let e = err_text(colmap::read_model(&t.0));
    assert!(
        e.contains("cameras.txt") && e.contains("line 2") && e.contains("'99'"),
        "{e}"
    );
    // And a wrong number of parameters.
    std::fs::write(t.0.join("cameras.txt"), "1 PINHOLE 10 10 1 2 3\n").unwrap();
    let e = err_text(colmap::read_model(&t.0));
    assert!(
        e.contains("cameras.txt") && e.contains("needs 4 parameters, found 3"),
        "{e}"
    );
    // A missing model file is named.
    std::fs::remove_file(t.0.join("points3D.txt")).unwrap();
    std::fs::write(t.0.join("cameras.txt"), "1 PINHOLE 10 10 1 2 3 4\n").unwrap();
    let e = err_text(colmap::read_model(&t.0));
    assert!(e.contains("points3D.bin") && e.contains("not found"), "{e}");
}

#[test]
fn auto_ndc_keeps_euclidean_rays_for_a_capture_that_turns_around_its_object() {
    let Some(dir) = beer() else {
        eprintln!("skipping: shared data absent");
        return;
    };
    let opts = LoadOptions {
        downscale: 8,
        ..LoadOptions::default()
    };
    let ds = llff::load(&dir, &opts).unwrap();
    // Independent check of the spread: after recentring the mean viewing axis is +z, so each
    // camera's angle to it is acos of its axis' z component.
    let angles: Vec<f64> = ds
        .views
        .iter()
        .map(|v| {
            math::column(&v.camera.pose.rotation, 2)[2]
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        })
        .collect();
    let widest = angles.iter().copied().fold(0.0, f64::max);
    assert!(
        angles[16] > 60.0,
        "camera 16 looks {:.1}° off the mean",
        angles[16]
    );
    let poses: Vec<Pose> = ds.views.iter().map(|v| v.camera.pose).collect();
    assert!((llff::view_spread_deg(&poses) - widest).abs() < 1e-6);
    assert!(
        ds.ndc.is_none(),
        "beer's cameras span an arc: auto must not pick NDC"
    );
    assert_eq!(ds.kind, nerf_data::SceneKind::ForwardFacing);
    assert!(
        ds.notes
            .iter()
            .any(|n| n.contains("Euclidean") && n.contains("--ndc on")),
        "the choice is explained: {:?}",
        ds.notes
    );
    assert!(ds.near > 0.0 && ds.far > ds.near);

    // The spiral looks at the point the optical axes converge on (the can), which every
    // training camera sees in its image.
    let focus = llff::axes_focus(&poses).expect("an arc of cameras converges");
    for v in &ds.views {
        let (u, vv, depth) = v.camera.project(focus).expect("in front of every camera");
        let k = v.camera.intrinsics;
        assert!(depth > 0.0 && (0.0..k.width as f64).contains(&u) && (0.0..k.height as f64).contains(&vv));
    }
    for p in llff::spiral_path(&ds, 12) {
        let forward = math::normalize(math::scale(math::column(&p.rotation, 2), -1.0));
        let to_focus = math::normalize(math::sub(focus, p.translation));
        assert!(
            math::dot(forward, to_focus) > 1.0 - 1e-9,
            "spiral camera looks past the focus"
        );
    }
}
