//! A triangle mesh from a TSDF grid by marching tetrahedra: each cell of
//! eight neighbouring voxel centres whose voxels were all observed is cut
//! into six tetrahedra around its main diagonal (the same cut in every
//! cell, so neighbouring cells share their faces' diagonals and the mesh
//! has no cracks), and each tetrahedron whose corners change sign gives
//! one or two triangles with vertices interpolated linearly on its edges.
//! A vertex on an edge between two voxels is shared by every triangle that
//! uses that edge. No case table: a tetrahedron has three kinds of sign
//! pattern (one, two or three corners inside). Triangles face the side of
//! positive distance (outwards, towards the cameras). The result depends
//! only on the grid: cells are visited in order, vertices numbered as met.

use glam::DVec3;
use std::collections::HashMap;
use tgs_pipelines::HostTsdf;

/// An indexed triangle mesh with a colour per vertex.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub colors: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// The six tetrahedra of a cell; corner c is at offset (c & 1, c >> 1 & 1,
/// c >> 2 & 1). Each contains the diagonal 0-7.
const TETS: [[usize; 4]; 6] = [[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7], [0, 5, 1, 7]];

/// Extract the zero level set of `grid` (voxel centres at `origin +
/// (i + 0.5) voxel`) over the cells whose eight voxels all have a weight
/// above `min_weight`.
pub fn extract(grid: &HostTsdf, origin: [f32; 3], voxel: f32, min_weight: f32) -> Mesh {
    let [nx, ny, nz] = grid.dims.map(|d| d as usize);
    let mut mesh = Mesh::default();
    if nx < 2 || ny < 2 || nz < 2 || grid.tsdf.len() < nx * ny * nz {
        return mesh;
    }
    let index = |i: usize, j: usize, k: usize| i + nx * (j + ny * k);
    let observed = |v: usize| grid.weight[v] > min_weight && grid.tsdf[v].is_finite();
    let centre = |v: usize| -> [f64; 3] {
        let ijk = [v % nx, (v / nx) % ny, v / (nx * ny)];
        std::array::from_fn(|c| origin[c] as f64 + (ijk[c] as f64 + 0.5) * voxel as f64)
    };
    let mut vertex_of: HashMap<(usize, usize), u32> = HashMap::new();
    // The vertex on the edge from voxel a (inside) to voxel b (outside).
    let mut vertex = |mesh: &mut Mesh, a: usize, b: usize| -> (u32, [f64; 3]) {
        let key = (a.min(b), a.max(b));
        let (sa, sb) = (grid.tsdf[a] as f64, grid.tsdf[b] as f64);
        // sa < 0 <= sb: t in [0, 1).
        let t = sa / (sa - sb);
        let (pa, pb) = (centre(a), centre(b));
        let p = [0, 1, 2].map(|k| pa[k] + t * (pb[k] - pa[k]));
        let id = *vertex_of.entry(key).or_insert_with(|| {
            mesh.positions.push(p.map(|v| v as f32));
            mesh.colors.push([0, 1, 2].map(|c| (grid.rgb[c][a] as f64 + t * (grid.rgb[c][b] as f64 - grid.rgb[c][a] as f64)) as f32));
            (mesh.positions.len() - 1) as u32
        });
        (id, p)
    };
    for k in 0..nz - 1 {
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                let corner: [usize; 8] = std::array::from_fn(|c| index(i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1)));
                let inside = corner.map(|v| grid.tsdf[v] < 0.0);
                if inside.iter().all(|&s| s) || inside.iter().all(|&s| !s) || !corner.iter().all(|&v| observed(v)) {
                    continue;
                }
                for tet in TETS {
                    let v = tet.map(|c| corner[c]);
                    let (ins, outs): (Vec<usize>, Vec<usize>) = v.iter().partition(|&&x| grid.tsdf[x] < 0.0);
                    let tris: Vec<[(usize, usize); 3]> = match ins.len() {
                        1 => vec![[(ins[0], outs[0]), (ins[0], outs[1]), (ins[0], outs[2])]],
                        3 => vec![[(ins[0], outs[0]), (ins[1], outs[0]), (ins[2], outs[0])]],
                        2 => vec![[(ins[0], outs[0]), (ins[0], outs[1]), (ins[1], outs[1])], [(ins[0], outs[0]), (ins[1], outs[1]), (ins[1], outs[0])]],
                        _ => continue,
                    };
                    // Outwards: from the inside corners towards the outside ones.
                    let mean = |s: &[usize]| {
                        let sum = s.iter().fold([0.0; 3], |acc, &x| {
                            let p = centre(x);
                            [0, 1, 2].map(|c| acc[c] + p[c])
                        });
                        sum.map(|v| v / s.len() as f64)
                    };
                    let out_dir = DVec3::from(mean(&outs)) - DVec3::from(mean(&ins));
                    for tri in tris {
                        let [(a0, b0), (a1, b1), (a2, b2)] = tri;
                        let (i0, p0) = vertex(&mut mesh, a0, b0);
                        let (i1, p1) = vertex(&mut mesh, a1, b1);
                        let (i2, p2) = vertex(&mut mesh, a2, b2);
                        let (p0, p1, p2) = (DVec3::from(p0), DVec3::from(p1), DVec3::from(p2));
                        let d = (p1 - p0).cross(p2 - p0).dot(out_dir);
                        if i0 == i1 || i1 == i2 || i0 == i2 || d == 0.0 {
                            continue;
                        }
                        mesh.triangles.push(if d > 0.0 { [i0, i1, i2] } else { [i0, i2, i1] });
                    }
                }
            }
        }
    }
    mesh
}
