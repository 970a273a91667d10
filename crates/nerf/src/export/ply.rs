//! Binary little-endian PLY, the format MeshLab, Blender and Open3D read: vertices with
//! position, optional normal and 8-bit colour, and optional triangles.

use std::path::Path;

use crate::error::Result;

/// Writes `vertices` (with `normals` when given, and `colors`) and `faces` to `path`, atomically.
pub fn write_ply(
    path: &Path,
    vertices: &[[f32; 3]],
    normals: Option<&[[f32; 3]]>,
    colors: &[[u8; 3]],
    faces: &[[u32; 3]],
) -> Result<()> {
    let mut header = String::from("ply\nformat binary_little_endian 1.0\ncomment written by nerf-rs\n");
    header += &format!("element vertex {}\n", vertices.len());
    header += "property float x\nproperty float y\nproperty float z\n";
    if normals.is_some() {
        header += "property float nx\nproperty float ny\nproperty float nz\n";
    }
    header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    if !faces.is_empty() {
        header += &format!(
            "element face {}\nproperty list uchar int vertex_indices\n",
            faces.len()
        );
    }
    header += "end_header\n";
    let per_vertex = 12 + if normals.is_some() { 12 } else { 0 } + 3;
    let mut out = Vec::with_capacity(header.len() + per_vertex * vertices.len() + 13 * faces.len());
    out.extend(header.as_bytes());
    for (k, v) in vertices.iter().enumerate() {
        v.iter().for_each(|x| out.extend(x.to_le_bytes()));
        if let Some(n) = normals {
            n[k].iter().for_each(|x| out.extend(x.to_le_bytes()));
        }
        out.extend(colors.get(k).copied().unwrap_or([200; 3]));
    }
    for f in faces {
        out.push(3);
        f.iter().for_each(|&i| out.extend((i as i32).to_le_bytes()));
    }
    Ok(nerf_data::image::write_atomic(path, &out)?)
}
