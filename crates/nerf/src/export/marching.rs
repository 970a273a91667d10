//! Level sets of a scalar grid by marching tetrahedra: each grid cube is cut into six
//! tetrahedra around its main diagonal (neighbouring cubes cut their shared faces the same way,
//! so the surface has no cracks), and each tetrahedron that the level set crosses gives one
//! triangle or two. No case tables; vertices on shared edges are shared.

use std::collections::HashMap;

/// A scalar grid: `values[(k·ny + j)·nx + i]` at `origin + (i, j, k)·spacing`.
pub struct Grid<'a> {
    pub values: &'a [f32],
    pub dims: [usize; 3],
    pub origin: [f32; 3],
    pub spacing: f32,
}

/// A triangle mesh; `normals` are unit, pointing from high values to low (out of a solid whose
/// inside is above the level).
#[derive(Clone, Debug, Default)]
pub struct TriMesh {
    pub vertices: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub faces: Vec<[u32; 3]>,
}

/// The six tetrahedra of a cube, as cube corners (bit 0: +x, bit 1: +y, bit 2: +z), all
/// sharing the diagonal 0–7.
const TETS: [[usize; 4]; 6] = [
    [0, 7, 1, 3],
    [0, 7, 3, 2],
    [0, 7, 2, 6],
    [0, 7, 6, 4],
    [0, 7, 4, 5],
    [0, 7, 5, 1],
];

impl Grid<'_> {
    fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (k * self.dims[1] + j) * self.dims[0] + i
    }

    fn position(&self, p: usize) -> [f32; 3] {
        let [nx, ny, _] = self.dims;
        let c = [p % nx, (p / nx) % ny, p / (nx * ny)];
        std::array::from_fn(|d| self.origin[d] + c[d] as f32 * self.spacing)
    }

    /// Central-difference gradient at grid point `p` (one-sided at the border).
    fn gradient(&self, p: usize) -> [f32; 3] {
        let [nx, ny, nz] = self.dims;
        let c = [p % nx, (p / nx) % ny, p / (nx * ny)];
        let mut g = [0.0f32; 3];
        for axis in 0..3 {
            let n = [nx, ny, nz][axis];
            let (lo, hi) = (c[axis].saturating_sub(1), (c[axis] + 1).min(n - 1));
            if hi == lo {
                continue;
            }
            let at = |v: usize| {
                let mut q = c;
                q[axis] = v;
                self.values[self.index(q[0], q[1], q[2])]
            };
            g[axis] = (at(hi) - at(lo)) / ((hi - lo) as f32 * self.spacing);
        }
        g
    }
}

/// The level set `value = level` of `grid`.
pub fn level_set(grid: &Grid<'_>, level: f32) -> TriMesh {
    let [nx, ny, nz] = grid.dims;
    let mut mesh = TriMesh::default();
    if nx < 2 || ny < 2 || nz < 2 {
        return mesh;
    }
    let mut on_edge: HashMap<(u32, u32), u32> = HashMap::new();
    let above = |p: usize| grid.values[p] > level;
    for k in 0..nz - 1 {
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                let corners: [usize; 8] =
                    std::array::from_fn(|c| grid.index(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)));
                let inside = corners.map(above);
                if inside.iter().all(|&b| b) || inside.iter().all(|&b| !b) {
                    continue;
                }
                for tet in TETS {
                    let pts = tet.map(|c| corners[c]);
                    let (ins, outs): (Vec<usize>, Vec<usize>) = pts.iter().partition(|&&p| above(p));
                    let mut vertex =
                        |a: usize, b: usize| edge_vertex(grid, level, a, b, &mut on_edge, &mut mesh);
                    match (ins.len(), outs.len()) {
                        (1, 3) | (3, 1) => {
                            let (lone, rest) = if ins.len() == 1 {
                                (ins[0], &outs)
                            } else {
                                (outs[0], &ins)
                            };
                            let tri = [
                                vertex(lone, rest[0]),
                                vertex(lone, rest[1]),
                                vertex(lone, rest[2]),
                            ];
                            push_oriented(&mut mesh, tri);
                        }
                        (2, 2) => {
                            let q = [
                                vertex(ins[0], outs[0]),
                                vertex(ins[0], outs[1]),
                                vertex(ins[1], outs[1]),
                                vertex(ins[1], outs[0]),
                            ];
                            push_oriented(&mut mesh, [q[0], q[1], q[2]]);
                            push_oriented(&mut mesh, [q[0], q[2], q[3]]);
                        }
                        _ => {}
                    }
                }
            }
        }
    }
    mesh
}

/// The vertex where the level set crosses the grid edge a–b (made once per edge).
fn edge_vertex(
    grid: &Grid<'_>,
    level: f32,
    a: usize,
    b: usize,
    on_edge: &mut HashMap<(u32, u32), u32>,
    mesh: &mut TriMesh,
) -> u32 {
    let key = (a.min(b) as u32, a.max(b) as u32);
    if let Some(&v) = on_edge.get(&key) {
        return v;
    }
    let (va, vb) = (grid.values[a], grid.values[b]);
    let t = ((level - va) / (vb - va)).clamp(0.0, 1.0);
    let (pa, pb) = (grid.position(a), grid.position(b));
    let (ga, gb) = (grid.gradient(a), grid.gradient(b));
    let g: [f32; 3] = std::array::from_fn(|d| ga[d] + t * (gb[d] - ga[d]));
    let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    let normal = if len > 0.0 { g.map(|x| -x / len) } else { [0.0; 3] };
    let id = mesh.vertices.len() as u32;
    mesh.vertices
        .push(std::array::from_fn(|d| pa[d] + t * (pb[d] - pa[d])));
    mesh.normals.push(normal);
    on_edge.insert(key, id);
    id
}

/// Adds the triangle wound so that its normal (right-hand rule) points along the vertices'
/// outward normals. Degenerate triangles (a vertex on a grid point) are dropped.
fn push_oriented(mesh: &mut TriMesh, tri: [u32; 3]) {
    if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
        return;
    }
    let p = tri.map(|v| mesh.vertices[v as usize]);
    let (e1, e2) = (sub(p[1], p[0]), sub(p[2], p[0]));
    let n = cross(e1, e2);
    let out = tri
        .map(|v| mesh.normals[v as usize])
        .iter()
        .fold([0.0f32; 3], |s, m| [s[0] + m[0], s[1] + m[1], s[2] + m[2]]);
    if n[0] * out[0] + n[1] * out[1] + n[2] * out[2] < 0.0 {
        mesh.faces.push([tri[0], tri[2], tri[1]]);
    } else {
        mesh.faces.push(tri);
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// r − |x| (a solid sphere of radius `r` above level 0) on an n³ grid over [−1, 1]³.
    fn sphere_values(n: usize, r: f32) -> Vec<f32> {
        let spacing = 2.0 / (n - 1) as f32;
        (0..n * n * n)
            .map(|p| {
                let c = [p % n, (p / n) % n, p / (n * n)].map(|c| -1.0 + c as f32 * spacing);
                r - (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
            })
            .collect()
    }

    #[test]
    fn sphere_vertices_lie_on_the_sphere_and_the_mesh_is_closed() {
        let (n, r) = (33, 0.6f32);
        let values = sphere_values(n, r);
        let grid = Grid {
            values: &values,
            dims: [n; 3],
            origin: [-1.0; 3],
            spacing: 2.0 / (n - 1) as f32,
        };
        let mesh = level_set(&grid, 0.0);
        assert!(mesh.faces.len() > 1000, "{} faces", mesh.faces.len());
        let h = grid.spacing;
        for (v, nrm) in mesh.vertices.iter().zip(&mesh.normals) {
            let d = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            // Linear interpolation of a curved distance field along an edge (up to √3 cells long).
            assert!((d - r).abs() < 0.1 * h, "vertex at radius {d}");
            // Outward normal = radial direction.
            let cos = (v[0] * nrm[0] + v[1] * nrm[1] + v[2] * nrm[2]) / d;
            assert!(cos > 0.98, "normal cos {cos}");
        }
        // Closed and consistently wound: every edge is used once in each direction.
        let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
        for f in &mesh.faces {
            for e in 0..3 {
                let (a, b) = (f[e], f[(e + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
            }
        }
        assert!(
            edges.values().all(|&c| c == 0),
            "open or inconsistently wound edges"
        );
        // Area near 4πr² (the inscribed polyhedron is slightly smaller).
        let area: f32 = mesh
            .faces
            .iter()
            .map(|f| {
                let p = f.map(|v| mesh.vertices[v as usize]);
                let c = cross(sub(p[1], p[0]), sub(p[2], p[0]));
                0.5 * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
            })
            .sum();
        let want = 4.0 * std::f32::consts::PI * r * r;
        assert!((area - want).abs() / want < 0.02, "area {area} vs {want}");
        // Outward winding: the signed volume is positive and near 4/3 πr³.
        let volume: f32 = mesh
            .faces
            .iter()
            .map(|f| {
                let p = f.map(|v| mesh.vertices[v as usize]);
                let c = cross(p[1], p[2]);
                (p[0][0] * c[0] + p[0][1] * c[1] + p[0][2] * c[2]) / 6.0
            })
            .sum();
        let want = 4.0 / 3.0 * std::f32::consts::PI * r * r * r;
        assert!((volume - want).abs() / want < 0.03, "volume {volume} vs {want}");
    }

    #[test]
    fn uniform_grids_have_no_surface() {
        let values = vec![1.0f32; 27];
        let grid = Grid {
            values: &values,
            dims: [3; 3],
            origin: [0.0; 3],
            spacing: 1.0,
        };
        assert!(level_set(&grid, 0.5).faces.is_empty());
        assert!(level_set(&grid, 1.5).faces.is_empty());
    }
}
