//! Stage II's cube map started from the scene (harness/train/src/train/stages/reflection/env_init.rs):
//! the texel directions against the f64 reference's cube lookup, and a room
//! of six two-tone walls around the reflection set's box, with a Gaussian
//! inside the box that the map must leave out, and the distance to each
//! wall the map's depth records.

use tgs::train::stages::reflection::env_init::{outside_box, scene_env_map, SceneLight};
use tgs::train::stages::reflection::seed::quat_for_normal;
use tgs::train::stages::scattering::init::SH_C0;
use tgs_pipelines::{HostEnvMap, HostGaussians};
use tgs_tests::reflection_ref as rr;
use tgs_tests::{check_validation, ctx_shared};

#[test]
fn texel_directions_invert_the_cube_lookup() {
    for res in [1u32, 2, 5, 128] {
        for face in 0..6u32 {
            for row in 0..res {
                for col in 0..res {
                    let d = HostEnvMap::texel_direction(res, face, row, col);
                    let (f, x, y) = rr::cube_coords(d.map(f64::from));
                    let s = 2.0 / res as f64;
                    let want = ((col as f64 + 0.5) * s - 1.0, (row as f64 + 0.5) * s - 1.0);
                    assert_eq!(f, face as usize, "res {res} texel ({face}, {row}, {col}): direction {d:?} looks up face {f}");
                    assert!((x - want.0).abs() < 1e-6 && (y - want.1).abs() < 1e-6, "res {res} texel ({face}, {row}, {col}): ({x}, {y}) against {want:?}");
                }
            }
        }
    }
}

/// The colour of the wall beyond cube face `face`, half as bright where its
/// first in-plane coordinate (`offset`, from the centre) is negative, so
/// that a mirrored face shows.
fn wall_colour(face: usize, offset: f32) -> [f32; 3] {
    let c = [[0.9, 0.1, 0.1], [0.1, 0.9, 0.1], [0.1, 0.1, 0.9], [0.9, 0.9, 0.1], [0.1, 0.9, 0.9], [0.9, 0.1, 0.9]][face];
    if offset < -0.1 {
        c.map(|v| v * 0.5)
    } else {
        c
    }
}

fn push(g: &mut HostGaussians, p: [f32; 3], normal: [f32; 3], scale: f32, colour: [f32; 3]) {
    let mut f = vec![0.0f32; 3 * 16];
    for c in 0..3 {
        f[c] = (colour[c] - 0.5) / SH_C0;
    }
    g.push(p, [scale.ln(); 2], quat_for_normal(normal), 6.0, &f);
}

/// Six walls at distance 4 from `centre`, surfels 0.5 apart; one white
/// Gaussian 0.3 off the centre along +x.
fn room(centre: [f32; 3]) -> (HostGaussians, usize) {
    let mut g = HostGaussians::new(3, 16);
    for face in 0..6 {
        let axis = face / 2;
        let sign = if face % 2 == 0 { 1.0 } else { -1.0 };
        let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
        for i in -9..=9 {
            for j in -9..=9 {
                let mut p = centre;
                p[axis] += 4.0 * sign;
                p[a] += 0.5 * i as f32;
                p[b] += 0.5 * j as f32;
                let mut n = [0.0; 3];
                n[axis] = -sign;
                push(&mut g, p, n, 0.4, wall_colour(face, 0.5 * i as f32));
            }
        }
    }
    let walls = g.len();
    push(&mut g, [centre[0] + 0.3, centre[1], centre[2]], [-1.0, 0.0, 0.0], 0.3, [1.0, 1.0, 1.0]);
    (g, walls)
}

#[test]
fn the_map_sees_the_walls_around_the_box_and_not_what_is_in_it() {
    let ctx = ctx_shared();
    let centre = [0.5f32, -1.0, 2.0];
    let (scat, walls) = room(centre);
    // The reflection set: the corners of a cube of half-size 0.5 about the centre.
    let mut refl = Vec::new();
    for k in 0..8 {
        refl.extend([0, 1, 2].map(|a| centre[a] + if k >> a & 1 == 1 { 0.5 } else { -0.5 }));
    }
    assert_eq!(outside_box(&scat, centre, [0.55; 3]).len(), walls, "the box keeps the walls and drops the Gaussian inside");
    let res = 8;
    let (env, info) = scene_env_map(ctx, SceneLight { set: &scat, sh_degree: 0, background: &[0.0; 3] }, &refl, res, 1e-15, false).unwrap();
    assert_eq!(info.rendered, walls, "Gaussians rendered");
    for a in 0..3 {
        assert!((info.centre[a] - centre[a]).abs() < 1e-5, "box centre {:?}", info.centre);
    }
    let mut checked = 0;
    for face in 0..6u32 {
        for row in 0..res {
            for col in 0..res {
                // Where the texel's direction meets its wall, and the wall's colour there.
                let d = HostEnvMap::texel_direction(res, face, row, col);
                let axis = face as usize / 2;
                let offset = 4.0 * d[(axis + 1) % 3] / d[axis].abs();
                let other = 4.0 * d[(axis + 2) % 3] / d[axis].abs();
                // Away from the colour boundary and the room's edges.
                if offset.abs() < 1.0 || offset.abs() > 3.0 || other.abs() > 3.0 {
                    continue;
                }
                let got = env.texel_rgb(face, row, col);
                let want = wall_colour(face as usize, offset);
                for c in 0..3 {
                    assert!((got[c] - want[c]).abs() < 0.03, "face {face} texel ({row}, {col}): {got:?}, the wall is {want:?}");
                }
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 6 * 24, "texels checked");
    let (again, _) = scene_env_map(ctx, SceneLight { set: &scat, sh_degree: 0, background: &[0.0; 3] }, &refl, res, 1e-15, false).unwrap();
    assert!(env.raw.iter().zip(&again.raw).all(|(a, b)| a.to_bits() == b.to_bits()), "a second map differs");
    // With depth: each texel's distance from the centre to its wall
    // (4 / the axis component of the unit direction), the same colours,
    // and the lookup's proxy at the centre.
    let (deep, info) = scene_env_map(ctx, SceneLight { set: &scat, sh_degree: 0, background: &[0.0; 3] }, &refl, res, 1e-15, true).unwrap();
    assert!(deep.raw.iter().zip(&env.raw).all(|(a, b)| a.to_bits() == b.to_bits()), "depth changed the colours");
    let proxy = deep.proxy.expect("a depth map's proxy");
    assert!((0..3).all(|a| (proxy.centre[a] - centre[a]).abs() < 1e-5), "proxy {proxy:?}");
    let depth = deep.depth.as_ref().expect("the depth");
    let di = info.depth.expect("the depth's summary");
    assert_eq!(di.surface_share, 1.0, "every texel shows a wall");
    assert!(di.nearest > 3.9 && di.nearest < 4.2 && di.farthest > 6.0 && di.farthest < 8.0, "{di:?}");
    let mut checked = 0;
    for face in 0..6u32 {
        for row in 0..res {
            for col in 0..res {
                let d = HostEnvMap::texel_direction(res, face, row, col);
                let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                let axis = face as usize / 2;
                // Away from the room's edges, where the walls overlap.
                if (1..3).any(|k| (4.0 * d[(axis + k) % 3] / d[axis].abs()).abs() > 3.0) {
                    continue;
                }
                let want = 4.0 * len / d[axis].abs();
                let got = depth[((face * res + row) * res + col) as usize];
                assert!((got - want).abs() < 0.02 * want, "face {face} texel ({row}, {col}): depth {got}, the wall is {want} away");
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 6 * 36, "texels checked");
    // A reflection set around the whole room leaves nothing to render: the
    // grey map, not an error.
    let big: Vec<f32> = [-10.0f32, 10.0].iter().flat_map(|o| centre.map(|c| c + o)).collect();
    let (grey, info) = scene_env_map(ctx, SceneLight { set: &scat, sh_degree: 0, background: &[0.0; 3] }, &big, res, 1e-15, false).unwrap();
    assert_eq!(info.rendered, 0);
    assert!(grey.raw.iter().all(|&v| v == 0.0), "the grey map");
    check_validation(ctx);
}
