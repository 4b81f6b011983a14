//! Initial points (harness/train/src/train/stages/scattering/init.rs), on the CPU: the far-field
//! points that random initialisation adds beyond its cube and the cameras,
//! and the neighbour distances that size the initial Gaussians
//! (harness/train/src/train/stages/scattering/knn.rs).

use tgs::train::stages::scattering::init::{far_points, random_points};
use tgs::train::stages::scattering::knn::knn3_mean_sq;
use tgs_pipelines::Camera;
use tgs_pipelines::Rng;
use tgs_tests::raster_util::bits;

fn ring(n: usize, radius: f32, height: f32) -> Vec<Camera> {
    (0..n)
        .map(|i| {
            let a = i as f32 / n as f32 * std::f32::consts::TAU;
            Camera::look_at([radius * a.cos(), radius * a.sin(), height], [0.0, 0.0, 0.3], [0.0, 0.0, 1.0], 0.8, 48, 40)
        })
        .collect()
}

/// View-space position of `x` in `cam`.
fn view(cam: &Camera, x: [f32; 3]) -> [f32; 3] {
    let m = &cam.world_to_view;
    [0, 1, 2].map(|r| m[r][0] * x[0] + m[r][1] * x[1] + m[r][2] * x[2] + m[r][3])
}

/// Whether `x` is in front of `cam`, inside its image, at most `far` deep.
fn seen(cam: &Camera, x: [f32; 3], far: f32) -> bool {
    let p = view(cam, x);
    let (u, v) = (cam.fx * p[0] / p[2] + cam.cx, cam.fy * p[1] / p[2] + cam.cy);
    p[2] > 0.0 && p[2] <= far * 1.0001 && u >= -0.51 && v >= -0.51 && u <= cam.width as f32 - 0.49 && v <= cam.height as f32 - 0.49
}

#[test]
fn far_points_lie_beyond_the_cube_and_the_cameras_inside_the_views() {
    let cams = ring(12, 4.0, 1.5);
    let (half, far) = (1.3, 120.0);
    // The camera sphere as Dataset::extent makes it: 1.1 x the cameras' reach.
    let sphere = ([0.0, 0.0, 1.5], 4.4);
    let p = far_points(3000, &cams, half, sphere, far, &mut Rng::new(7));
    assert_eq!(p.positions.len(), 3000);
    assert_eq!(p.colors.len(), 3000);
    let depth = |x: [f32; 3]| cams.iter().filter(|c| seen(c, x, far)).map(|c| view(c, x)[2]).fold(f32::INFINITY, f32::min);
    let mut depths = Vec::new();
    for (x, c) in p.positions.iter().zip(&p.colors) {
        assert!(x.iter().any(|v| v.abs() > half), "{x:?} is inside the cube");
        // Nothing among the cameras: every point is farther from the ring's
        // centre than any camera, so none sits in front of a view taken from it.
        let r = (0..3).map(|k| (x[k] - sphere.0[k]).powi(2)).sum::<f32>().sqrt();
        assert!(r >= 4.4 * 0.9999, "{x:?} is {r} from the centre, inside the camera sphere");
        let d = depth(*x);
        assert!(d.is_finite(), "{x:?} is in no view's frustum within depth {far}");
        depths.push(d);
        assert!(c.iter().all(|v| (0.5..0.5 + 1.0 / 255.0).contains(v)), "colour {c:?}");
    }
    // Uniform in inverse depth: as many points per unit of 1/z near as far,
    // so most are near the scene and some reach far out.
    depths.sort_by(f32::total_cmp);
    let median = depths[depths.len() / 2];
    // (Uniform in depth would put the median near far / 2.)
    assert!(median < far / 8.0, "median depth {median}");
    assert!(depths.iter().filter(|&&d| d > 30.0).count() > 30, "none far out: max {}", depths[depths.len() - 1]);
    // Same generator state, same points.
    assert_eq!(far_points(3000, &cams, half, sphere, far, &mut Rng::new(7)).positions, p.positions);
}

#[test]
fn far_points_start_at_the_cube_when_the_cameras_are_inside_it() {
    // Cameras inside a large cube: the cube's exit is the nearer bound, and
    // a camera sphere smaller than the cube changes nothing.
    let cams = ring(8, 1.0, 0.5);
    let (half, far) = (3.0, 60.0);
    let a = far_points(500, &cams, half, ([0.0, 0.0, 0.5], 1.1), far, &mut Rng::new(3));
    let b = far_points(500, &cams, half, ([0.0, 0.0, 0.5], 0.0), far, &mut Rng::new(3));
    assert_eq!(a.positions.len(), 500);
    assert_eq!(a.positions, b.positions);
    assert!(a.positions.iter().all(|x| x.iter().any(|v| v.abs() > half)));
}

#[test]
fn far_points_need_cameras_and_a_far_end() {
    let s = ([0.0, 0.0, 1.0], 4.4);
    assert!(far_points(100, &[], 1.3, s, 100.0, &mut Rng::new(1)).positions.is_empty());
    assert!(far_points(100, &ring(4, 4.0, 1.0), 1.3, s, 0.0, &mut Rng::new(1)).positions.is_empty());
    // A far end nearer than the cube's far side, or than the camera
    // sphere's: no ray has room, and the bounded retries end without points
    // rather than looping.
    assert!(far_points(100, &ring(4, 4.0, 1.0), 1.3, s, 2.0, &mut Rng::new(1)).positions.is_empty());
    // (A camera 4 from the centre of a sphere of radius 20 leaves it no nearer than 16.)
    assert!(far_points(100, &ring(4, 4.0, 1.0), 1.3, (s.0, 20.0), 15.0, &mut Rng::new(1)).positions.is_empty());
    assert!(far_points(0, &ring(4, 4.0, 1.0), 1.3, s, 100.0, &mut Rng::new(1)).positions.is_empty());
}

/// The mean of the 3 smallest squared distances to the other points, by
/// brute force, summed as `knn3_mean_sq` sums them (ascending).
fn knn3_brute(pts: &[[f32; 3]]) -> Vec<f32> {
    (0..pts.len())
        .map(|i| {
            let mut d: Vec<f32> = (0..pts.len()).filter(|&j| j != i).map(|j| (0..3).map(|k| (pts[i][k] - pts[j][k]).powi(2)).sum::<f32>()).collect();
            d.sort_by(|a, b| a.total_cmp(b));
            d.truncate(3);
            if d.is_empty() {
                1e-7
            } else {
                d.iter().sum::<f32>() / d.len() as f32
            }
        })
        .collect()
}

/// Exact against brute force, bit for bit, on what random initialisation
/// makes (a dense cube inside a far field 30 units out, which made the old
/// uniform grid quadratic), on duplicates, a line, a plane, and on 0 to 4
/// points.
#[test]
fn nearest_neighbour_distances_are_exact() {
    let cams = ring(8, 3.0, 1.0);
    let mut rng = Rng::new(7);
    let mut pts = random_points(1500, 1.3, &mut rng).positions;
    pts.extend(far_points(3000, &cams, 1.3, ([0.0, 0.0, 0.3], 3.5), 30.0, &mut rng).positions);
    // Duplicates: the nearest distance 0, and ties at every rank.
    pts.extend(pts[..200].to_vec());
    pts.extend(std::iter::repeat_n([0.25f32, -0.5, 0.75], 40));
    assert_eq!(bits(&knn3_mean_sq(&pts)), bits(&knn3_brute(&pts)), "cube + far field + duplicates");
    let line: Vec<[f32; 3]> = (0..500).map(|i| [0.1 * (i % 37) as f32, 2.0, -1.0]).collect();
    assert_eq!(bits(&knn3_mean_sq(&line)), bits(&knn3_brute(&line)), "points on a line, repeated");
    let plane: Vec<[f32; 3]> = (0..900).map(|i| [(i % 30) as f32 * 0.01, (i / 30) as f32 * 0.013, 5.0]).collect();
    assert_eq!(bits(&knn3_mean_sq(&plane)), bits(&knn3_brute(&plane)), "a grid in a plane");
    let same = vec![[1.0f32, 1.0, 1.0]; 100];
    assert!(knn3_mean_sq(&same).iter().all(|&d| d == 0.0), "identical points");
    for n in 0..5 {
        let few = &pts[..n];
        assert_eq!(bits(&knn3_mean_sq(few)), bits(&knn3_brute(few)), "{n} points");
    }
    assert_eq!(knn3_mean_sq(&pts[..1]), vec![1e-7]);
}
