//! Geometry out of a trained field: a triangle mesh of a density level set (marching tetrahedra
//! over a grid in the scene box, vertex colours from the field looking into the surface) and a
//! coloured point cloud of the surfaces the training views see, both as binary PLY. Any model
//! that answers [`Volume`] exports through the same code (the static model here, NSFF at a time).

pub mod cull;
pub mod marching;
pub mod ply;
pub mod score;

use burn::tensor::Device;
use nerf_core::field::FieldQuery;
use nerf_core::occupancy::OccupancyGrid;
use nerf_core::readback::read_back;
use nerf_data::Rays;
use nerf_data::image::to_u8;

use std::path::Path;
use std::time::Instant;

use crate::cli::{MeshArgs, PointsArgs};
use crate::error::{ModelError, Result};
use crate::field::FieldModule;
use crate::model::StaticModel;
use crate::renderer::{density_host, tensor};

pub use cull::{DepthView, cull_unseen, culling_cameras};
pub use marching::TriMesh;

/// What export needs of a trained model (at one time, for a space-time model).
pub trait Volume {
    /// The box to mesh, `[min, max]`.
    fn aabb(&self) -> [[f32; 3]; 2];
    /// Densities at `[N, 3]` host positions.
    fn density(&self, positions: &[f32]) -> Result<Vec<f32>>;
    /// Colours `[N, 3]` seen looking along the unit `dirs` (`[N, 3]`) at `positions`.
    fn color(&self, positions: &[f32], dirs: &[f32]) -> Result<Vec<f32>>;
}

/// A mesh with one colour per vertex.
pub struct ColoredMesh {
    pub mesh: TriMesh,
    pub colors: Vec<[u8; 3]>,
    /// Grid points per axis and their spacing (scene units).
    pub dims: [usize; 3],
    pub spacing: f32,
}

/// Mesh extraction settings.
#[derive(Clone, Debug)]
pub struct MeshOptions {
    /// Grid cells along the longest side of the box.
    pub resolution: usize,
    /// Density of the level set.
    pub threshold: f32,
}

/// Points per density query (one z-slice of a 256² grid).
const CHUNK: usize = 1 << 16;

/// How far behind a view's rendered surface (in grid cells) a vertex still counts as seen.
const CULL_SLACK_CELLS: f32 = 4.0;

/// Default density of the exported surface (`--threshold`).
pub const DEFAULT_THRESHOLD: f32 = 50.0;

/// Samples `volume`'s density on a grid over its box, extracts the level set at
/// `opts.threshold` and colours its vertices.
pub fn extract_mesh(volume: &dyn Volume, opts: &MeshOptions, show_progress: bool) -> Result<ColoredMesh> {
    let [lo, hi] = volume.aabb();
    let extent: [f32; 3] = std::array::from_fn(|d| (hi[d] - lo[d]).max(0.0));
    let spacing = extent.iter().cloned().fold(1e-6f32, f32::max) / opts.resolution.max(2) as f32;
    let dims = extent.map(|e| (e / spacing).ceil() as usize + 1);
    let [nx, ny, nz] = dims;
    let bar = progress(show_progress, nz as u64 + 1, "density grid");
    let mut values = Vec::with_capacity(nx * ny * nz);
    let mut slice = Vec::with_capacity(3 * nx * ny);
    for k in 0..nz {
        slice.clear();
        for j in 0..ny {
            for i in 0..nx {
                slice.extend([
                    lo[0] + i as f32 * spacing,
                    lo[1] + j as f32 * spacing,
                    lo[2] + k as f32 * spacing,
                ]);
            }
        }
        for part in slice.chunks(3 * CHUNK) {
            values.extend(volume.density(part)?);
        }
        bar.inc(1);
    }
    bar.set_message("marching");
    let grid = marching::Grid {
        values: &values,
        dims,
        origin: lo,
        spacing,
    };
    let mesh = marching::level_set(&grid, opts.threshold);
    bar.set_message("colours");
    let mut colors = Vec::with_capacity(mesh.vertices.len());
    for (v, n) in mesh.vertices.chunks(CHUNK).zip(mesh.normals.chunks(CHUNK)) {
        let positions: Vec<f32> = v.iter().flatten().copied().collect();
        // Look into the surface, against its outward normal.
        let dirs: Vec<f32> = n
            .iter()
            .flat_map(|n| {
                if n == &[0.0; 3] {
                    [0.0, 0.0, -1.0]
                } else {
                    n.map(|x| -x)
                }
            })
            .collect();
        let rgb = volume.color(&positions, &dirs)?;
        colors.extend(
            rgb.chunks_exact(3)
                .map(|c| [to_u8(c[0]), to_u8(c[1]), to_u8(c[2])]),
        );
    }
    bar.finish_and_clear();
    Ok(ColoredMesh {
        mesh,
        colors,
        dims,
        spacing,
    })
}

/// Coloured points.
#[derive(Clone, Debug, Default)]
pub struct PointCloud {
    pub positions: Vec<[f32; 3]>,
    pub colors: Vec<[u8; 3]>,
}

impl PointCloud {
    /// Adds the surface point of each rendered ray whose opacity reaches `min_opacity`: the ray
    /// at its expected depth (`depth` is opacity-weighted, as renders return it), with its colour.
    pub fn add_rendered(
        &mut self,
        rays: &Rays,
        rgb: &[f32],
        depth: &[f32],
        opacity: &[f32],
        min_opacity: f32,
    ) {
        for r in 0..rays.len() {
            let a = opacity[r];
            if a.is_nan() || a < min_opacity || !depth[r].is_finite() {
                continue;
            }
            let t = depth[r] / a;
            let (o, d) = (
                &rays.origins[3 * r..3 * r + 3],
                &rays.directions[3 * r..3 * r + 3],
            );
            self.positions
                .push([o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]);
            let c = &rgb[3 * r..3 * r + 3];
            self.colors.push([to_u8(c[0]), to_u8(c[1]), to_u8(c[2])]);
        }
    }
}

/// A progress bar with a message (hidden when `show` is false).
pub fn progress(show: bool, len: u64, what: &'static str) -> indicatif::ProgressBar {
    if !show {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{msg:>14} [{bar:40}] {pos}/{len} {elapsed}") {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_message(what);
    bar
}

/// Zeroes the densities of points in cells the occupancy grid marks empty: rendering never
/// samples there, so whatever the field holds there (never trained) must not become geometry.
pub fn mask_unoccupied(occupancy: Option<&OccupancyGrid>, positions: &[f32], sigma: &mut [f32]) {
    if let Some(grid) = occupancy {
        for (s, p) in sigma.iter_mut().zip(positions.chunks_exact(3)) {
            if !grid.is_occupied([p[0], p[1], p[2]]) {
                *s = 0.0;
            }
        }
    }
}

/// The static model as a [`Volume`]: its (fine) field, masked by its occupancy grid.
pub struct StaticVolume<'a, F: FieldModule> {
    pub model: &'a StaticModel<F>,
    pub device: &'a Device,
}

impl<F: FieldModule> Volume for StaticVolume<'_, F> {
    fn aabb(&self) -> [[f32; 3]; 2] {
        self.model.bounds.aabb
    }

    fn density(&self, positions: &[f32]) -> Result<Vec<f32>> {
        let mut sigma = density_host(&self.model.fields.field, positions, self.device)?;
        mask_unoccupied(self.model.occupancy.as_ref(), positions, &mut sigma);
        Ok(sigma)
    }

    fn color(&self, positions: &[f32], dirs: &[f32]) -> Result<Vec<f32>> {
        let plain = self.device.clone().inner();
        let field = self.model.fields.field.valid();
        let out = field.query(FieldQuery::new(tensor(positions.to_vec(), 3, &plain), dirs));
        Ok(read_back(out.rgb, "colour")?)
    }
}

/// Renders a camera's (opacity-weighted depth, opacity), for culling.
pub type RenderDepth<'a> = dyn Fn(&nerf_data::Camera) -> Result<(Vec<f32>, Vec<f32>)> + 'a;

/// `export mesh`: extracts the mesh of `volume`, writes it, says what it wrote and, for a scene
/// our generator made (`scene.json` beside the data), how far it lies from the true surfaces at
/// `time`. Returns the output path.
///
/// Unless `args.no_cull`, surfaces that none of `views` sees are dropped ([`cull_unseen`]);
/// `render_depth` renders a view's (depth, opacity).
pub fn run_mesh_export(
    volume: &dyn Volume,
    args: &MeshArgs,
    data: &Path,
    time: f64,
    views: &[nerf_data::Camera],
    render_depth: &RenderDepth<'_>,
) -> Result<std::path::PathBuf> {
    let out = args.out.clone().unwrap_or_else(|| args.run_dir.join("mesh.ply"));
    let start = Instant::now();
    let opts = MeshOptions {
        resolution: args.resolution,
        threshold: args.threshold,
    };
    let mut m = extract_mesh(volume, &opts, true)?;
    if !args.no_cull {
        let bar = progress(true, views.len() as u64, "culling views");
        let mut depth_views = Vec::with_capacity(views.len());
        for cam in views {
            let (depth, opacity) = render_depth(cam)?;
            depth_views.push(DepthView::new(*cam, &depth, &opacity));
            bar.inc(1);
        }
        bar.finish_and_clear();
        let slack = CULL_SLACK_CELLS * m.spacing;
        let dropped = cull_unseen(&mut m, &depth_views, slack);
        println!(
            "culled {dropped} triangles that none of {} training views sees (--no-cull keeps them)",
            views.len()
        );
    }
    if m.mesh.faces.is_empty() {
        return Err(ModelError::usage(
            &args.run_dir,
            format!(
                "no surface at density {} in the scene box (try a lower --threshold)",
                args.threshold
            ),
        ));
    }
    ply::write_ply(
        &out,
        &m.mesh.vertices,
        Some(&m.mesh.normals),
        &m.colors,
        &m.mesh.faces,
    )?;
    let [nx, ny, nz] = m.dims;
    println!(
        "wrote {}: {} vertices, {} triangles (grid {nx}x{ny}x{nz}, spacing {:.4}, density {}) in {:.1} s",
        out.display(),
        m.mesh.vertices.len(),
        m.mesh.faces.len(),
        m.spacing,
        args.threshold,
        start.elapsed().as_secs_f64()
    );
    report_score(volume.aabb(), &m.mesh.vertices, data, time, "vertices")?;
    Ok(out)
}

/// `export points`: writes `cloud`, says so, and scores it as [`run_mesh_export`] does.
pub fn run_points_export(
    cloud: &PointCloud,
    args: &PointsArgs,
    aabb: [[f32; 3]; 2],
    data: &Path,
    time: f64,
) -> Result<std::path::PathBuf> {
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| args.run_dir.join("points.ply"));
    if cloud.positions.is_empty() {
        return Err(ModelError::usage(
            &args.run_dir,
            format!("no rendered pixel reached opacity {}", args.min_opacity),
        ));
    }
    ply::write_ply(&out, &cloud.positions, None, &cloud.colors, &[])?;
    println!("wrote {}: {} points", out.display(), cloud.positions.len());
    report_score(aabb, &cloud.positions, data, time, "points")?;
    Ok(out)
}

/// Prints the geometry score against `scene.json`, when the data has one.
fn report_score(aabb: [[f32; 3]; 2], points: &[[f32; 3]], data: &Path, time: f64, what: &str) -> Result<()> {
    let Some(scene) = crate::diagnosis::load_scene(data)? else {
        return Ok(());
    };
    let size = (0..3)
        .map(|d| (aabb[1][d] - aabb[0][d]) as f64)
        .fold(0.0, f64::max);
    let s = score::score(&scene, time, points, size);
    println!(
        "against {}: {what} to the true surfaces: mean {:.4}, median {:.4}, {:.1} % within {:.4} (1 % of the scene size {:.2})",
        data.join(nerf_synth::SCENE_FILE).display(),
        s.accuracy_mean,
        s.accuracy_median,
        100.0 * s.accuracy_within,
        s.tolerance,
        s.scene_size
    );
    println!(
        "surfaces the test views see, to the nearest of the {what}: mean {:.4}, {:.1} % within {:.4}; Chamfer {:.4}",
        s.completeness_mean,
        100.0 * s.completeness_within,
        s.tolerance,
        s.chamfer
    );
    Ok(())
}

/// Export works in world space: captures rendered in NDC (forward-facing LLFF) have no bounded
/// box to mesh.
pub fn require_bounded(dataset: &nerf_data::Dataset, run_dir: &Path) -> Result<()> {
    if dataset.ndc.is_some() {
        return Err(ModelError::usage(
            run_dir,
            "this run renders in NDC (a forward-facing capture); export needs a run trained with --ndc off",
        ));
    }
    Ok(())
}

/// Every `stride`-th pixel of `camera` in each direction, row by row.
pub fn strided_pixels(camera: &nerf_data::Camera, stride: u32) -> Vec<u32> {
    let (w, h, s) = (
        camera.intrinsics.width,
        camera.intrinsics.height,
        stride.max(1) as usize,
    );
    (0..h)
        .step_by(s)
        .flat_map(|j| (0..w).step_by(s).map(move |i| j * w + i))
        .collect()
}
