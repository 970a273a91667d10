//! Format detection on the shared data and on small folder layouts.

use nerf_data::Format;
use nerf_data::load::{detect, load_video};

mod common;
use common::TempDir;

fn err(r: nerf_data::Result<impl std::fmt::Debug>) -> String {
    match r {
        Ok(v) => panic!("expected an error, got {v:?}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn shared_datasets_are_detected() {
    let Some(root) = nerf_data::shared_data() else {
        eprintln!("skipped: ../shared/data not found (set NERF_SHARED_DATA)");
        return;
    };
    assert_eq!(
        detect(&root.join("lego_tiny/tiny_nerf_data.npz")).unwrap(),
        Format::TinyNpz
    );
    // A folder holding a single .npz resolves to it.
    assert_eq!(detect(&root.join("lego_tiny")).unwrap(), Format::TinyNpz);
    assert_eq!(
        detect(&root.join("nerf_synthetic/lego")).unwrap(),
        Format::Blender
    );
    // beer has both poses_bounds.npy and a COLMAP model: poses_bounds.npy wins.
    assert_eq!(detect(&root.join("llff/beer")).unwrap(), Format::Llff);
    let msg = err(load_video(&root.join("nerf_synthetic/lego"), &Default::default()).map(|d| d.views.len()));
    assert!(
        msg.contains("transforms_train.json") && msg.contains("frames without time"),
        "{msg}"
    );
}

#[test]
fn folder_layouts_are_detected() {
    let colmap = TempDir::new("colmap");
    std::fs::create_dir_all(colmap.path().join("images")).unwrap();
    colmap.write(
        "sparse/0/cameras.txt",
        "# Camera list with one line of data per camera:\n",
    );
    colmap.write(
        "sparse/0/images.txt",
        "# Image list with two lines of data per image:\n",
    );
    colmap.write(
        "sparse/0/points3D.txt",
        "# 3D point list with one line of data per point:\n",
    );
    assert_eq!(detect(colmap.path()).unwrap(), Format::Colmap);

    // Without images/ the model alone is not a dataset, and the error says what is missing.
    std::fs::remove_dir(colmap.path().join("images")).unwrap();
    let msg = err(detect(colmap.path()));
    assert!(msg.contains("no images/ folder"), "{msg}");

    let blender = TempDir::new("blender");
    let pose = "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]";
    let json =
        format!(r#"{{"camera_angle_x": 0.7, "frames": [{{"file_path": "a", "transform_matrix": {pose}}}]}}"#);
    blender.write("transforms.json", &json);
    assert_eq!(detect(blender.path()).unwrap(), Format::Blender);

    let dnerf = TempDir::new("dnerf");
    let frame = format!(r#"{{"file_path": "a", "time": 0.0, "transform_matrix": {pose}}}"#);
    let json = format!(r#"{{"camera_angle_x": 0.7, "frames": [{frame}]}}"#);
    dnerf.write("transforms_train.json", &json);
    assert_eq!(detect(dnerf.path()).unwrap(), Format::DNerf);

    let llff = TempDir::new("llff");
    llff.write("poses_bounds.npy", "");
    assert_eq!(detect(llff.path()).unwrap(), Format::Llff);

    let two_npz = TempDir::new("two-npz");
    two_npz.write("a.npz", "");
    two_npz.write("b.npz", "");
    let msg = err(detect(two_npz.path()));
    assert!(msg.contains("a.npz, b.npz"), "{msg}");
}

#[test]
fn unknown_and_missing_paths_are_explained() {
    let unknown = TempDir::new("unknown");
    unknown.write("notes.txt", "hello");
    let msg = err(detect(unknown.path()));
    assert!(msg.contains(&*unknown.path().to_string_lossy()), "{msg}");
    for expected in [
        "transforms_train.json",
        "transforms.json",
        "poses_bounds.npy",
        "sparse/0/cameras.bin|txt",
        "*.npz",
    ] {
        assert!(msg.contains(expected), "{msg}");
    }
    let msg = err(detect(&unknown.path().join("notes.txt")));
    assert!(
        msg.contains("notes.txt") && msg.contains("not a dataset file"),
        "{msg}"
    );

    let missing = unknown.path().join("no-such-dataset");
    let msg = err(detect(&missing));
    assert!(
        msg.contains("no-such-dataset") && msg.contains("not found"),
        "{msg}"
    );
    let msg = err(nerf_data::load::load(&missing, &Default::default()).map(|d| d.views.len()));
    assert!(msg.contains("not found"), "{msg}");
}
