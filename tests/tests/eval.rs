//! The evaluation's normal errors on hand-made views: the reference normal
//! that faces each pixel's camera ray, and the MAE it scores against a wall
//! facing the camera (computed here independently, in f64); the error off
//! the mask, on the rest of the scene; the error the reflection layer
//! removes on chosen pixels.

use tgs::data::image_io::ImageF;
use tgs::data::View;
use tgs::eval::{layer_gain, normal_mae, normal_mae_outside, ray_facing_normals, residual_contrast};
use tgs_pipelines::Camera;

fn camera(w: u32, h: u32) -> Camera {
    Camera::look_at([1.0, -2.0, 1.5], [0.2, 0.3, 0.4], [0.0, 0.0, 1.0], 0.9, w, h)
}

fn view(cam: Camera, normals: Vec<f32>) -> View {
    let n = (cam.width * cam.height) as usize;
    View {
        name: "v".into(),
        camera: cam,
        image: ImageF::new(cam.width, cam.height, 3),
        normals: Some(ImageF { width: cam.width, height: cam.height, channels: 3, data: normals }),
        mask: Some(vec![true; n]),
    }
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    a.map(|c| c / l)
}

#[test]
fn ray_facing_normals_point_back_along_each_pixel_ray() {
    for (w, h) in [(7, 5), (1, 1), (16, 9)] {
        let cam = camera(w, h);
        let c = cam.centre().map(f64::from);
        let n = ray_facing_normals(&cam);
        assert_eq!(n.len(), (w * h) as usize);
        for (i, ni) in n.iter().enumerate() {
            // The pixel centre's point at depth 3 lies along -n from the camera.
            let p = cam.unproject((i as u32 % w) as f32, (i as u32 / w) as f32, 3.0).map(f64::from);
            let ray = unit([p[0] - c[0], p[1] - c[1], p[2] - c[2]]);
            let d: f64 = (0..3).map(|k| ray[k] * ni[k] as f64).sum();
            assert!((d + 1.0).abs() < 1e-5, "{w}x{h} pixel {i}: n {ni:?} against ray {ray:?}");
        }
    }
    // The middle pixel of an odd-sized image looks along the optical axis.
    let cam = camera(7, 5);
    let axis = unit([0.2 - 1.0, 0.3 + 2.0, 0.4 - 1.5]);
    let mid = ray_facing_normals(&cam)[2 * 7 + 3];
    assert!((0..3).all(|k| (mid[k] as f64 + axis[k]).abs() < 1e-5), "{mid:?} vs {axis:?}");
}

#[test]
fn ray_facing_mae_against_a_wall_is_the_mean_off_axis_angle() {
    let (w, h) = (16u32, 9u32);
    let cam = camera(w, h);
    // Against themselves: zero.
    let own: Vec<f32> = ray_facing_normals(&cam).into_iter().flatten().collect();
    let zero = normal_mae(&ray_facing_normals(&cam), &view(cam, own)).unwrap();
    assert!(zero < 0.05, "{zero}");
    // Against a wall facing the camera: each pixel's angle to the axis.
    let axis = unit([0.2 - 1.0, 0.3 + 2.0, 0.4 - 1.5]);
    let wall: Vec<f32> = (0..w * h).flat_map(|_| axis.map(|c| -c as f32)).collect();
    let f = cam.fx as f64;
    let expect = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64 - (w as f64 - 1.0) * 0.5, (i / w) as f64 - (h as f64 - 1.0) * 0.5);
            ((x * x + y * y).sqrt() / f).atan().to_degrees()
        })
        .sum::<f64>()
        / (w * h) as f64;
    let got = normal_mae(&ray_facing_normals(&cam), &view(cam, wall)).unwrap();
    assert!(expect > 5.0 && (got - expect).abs() < 0.01, "ray-facing MAE {got:.4} against {expect:.4} degrees");
}

#[test]
fn error_off_the_mask_counts_only_the_pixels_outside_it() {
    let (w, h) = (6u32, 4u32);
    let cam = camera(w, h);
    let n = (w * h) as usize;
    // Ground truth +z everywhere but one pixel off the mask without a normal.
    let mut gt: Vec<f32> = (0..n).flat_map(|_| [0.0, 0.0, 1.0]).collect();
    let hole = 5usize;
    gt[3 * hole..3 * hole + 3].fill(0.0);
    let mut v = view(cam, gt);
    // The left half is the mask.
    let mask: Vec<bool> = (0..n).map(|i| (i as u32 % w) < w / 2).collect();
    v.mask = Some(mask.clone());
    // On the mask the output is wrong by 90 degrees; off it, by 30 degrees
    // on the first row, exact elsewhere, and empty (90) on one pixel.
    let t = 30f32.to_radians();
    let empty = 23usize;
    let out: Vec<[f32; 3]> = (0..n)
        .map(|i| match (mask[i], i) {
            (true, _) => [1.0, 0.0, 0.0],
            (false, i) if i == empty => [0.0; 3],
            (false, i) if i < w as usize => [t.sin(), 0.0, t.cos()],
            _ => [0.0, 0.0, 1.0],
        })
        .collect();
    let off: Vec<usize> = (0..n).filter(|&i| !mask[i] && i != hole).collect();
    let want = off
        .iter()
        .map(|&i| {
            if i == empty {
                90.0
            } else if i < w as usize {
                30.0
            } else {
                0.0
            }
        })
        .sum::<f64>()
        / off.len() as f64;
    let got = normal_mae_outside(&out, &v).unwrap();
    assert!((got - want).abs() < 1e-3, "off-mask MAE {got} vs {want}");
    // On the mask: 90 everywhere.
    assert!((normal_mae(&out, &v).unwrap() - 90.0).abs() < 1e-3);
    // A mask over the whole image leaves nothing outside it.
    v.mask = Some(vec![true; n]);
    assert_eq!(normal_mae_outside(&out, &v), None);
}

#[test]
fn layer_gain_is_the_error_the_composite_removes_on_the_chosen_pixels() {
    // Four pixels, planar RGB. Pixel 0: the scattering layer is 0.2 off,
    // the composite exact (gain 0.2); pixel 1: the composite is worse by
    // 0.1 in red only (gain -0.1 / 3); pixel 2: both exact; pixel 3:
    // values past [0, 1] are clamped first, so 1.5 against a 1.0 target is
    // no error and the gain is 0.3 (scat 0.7, full 1.5).
    let n = 4;
    let gt = [0.5f32, 0.5, 0.4, 1.0, 0.5, 0.5, 0.4, 1.0, 0.5, 0.5, 0.4, 1.0];
    let scat = [0.7f32, 0.5, 0.4, 0.7, 0.7, 0.5, 0.4, 0.7, 0.7, 0.5, 0.4, 0.7];
    let full = [0.5f32, 0.6, 0.4, 1.5, 0.5, 0.5, 0.4, 1.5, 0.5, 0.5, 0.4, 1.5];
    let per = [0.2, -0.1 / 3.0, 0.0, 0.3];
    let all = layer_gain(&full, &scat, &gt, |_| true).unwrap();
    assert!((all - per.iter().sum::<f64>() / n as f64).abs() < 1e-6, "{all}");
    let odd = layer_gain(&full, &scat, &gt, |i| i % 2 == 1).unwrap();
    assert!((odd - (per[1] + per[3]) / 2.0).abs() < 1e-6, "{odd}");
    assert_eq!(layer_gain(&full, &scat, &gt, |_| false), None);
}

#[test]
fn residual_contrast_is_the_error_on_the_mask_over_the_error_off_it() {
    // Four pixels, planar RGB; pixels 0 and 1 on the mask. Errors, channel
    // means: pixel 0 0.3 (red and green 0.45, blue 0), pixel 1 0.1, pixel
    // 2 0.05, pixel 3 0.15 once 1.4 is clamped to 1 against a 0.85 target
    // (in every channel). On the mask (0.3 + 0.1) / 2 = 0.2, off it
    // (0.05 + 0.15) / 2 = 0.1: a contrast of 2.
    let gt = [0.5f32, 0.2, 0.4, 0.85, 0.5, 0.2, 0.4, 0.85, 0.5, 0.2, 0.4, 0.85];
    let scat = [0.95f32, 0.3, 0.45, 1.4, 0.05, 0.3, 0.45, 1.4, 0.5, 0.3, 0.45, 1.4];
    let mask = [true, true, false, false];
    let c = residual_contrast(&scat, &gt, &mask).unwrap();
    assert!((c - 2.0).abs() < 1e-6, "{c}");
    // The other way round: the reciprocal.
    let flipped = residual_contrast(&scat, &gt, &mask.map(|m| !m)).unwrap();
    assert!((flipped - 0.5).abs() < 1e-6, "{flipped}");
    // No contrast without both sides, or with nothing to compare against.
    assert_eq!(residual_contrast(&scat, &gt, &[true; 4]), None);
    assert_eq!(residual_contrast(&scat, &gt, &[false; 4]), None);
    assert_eq!(residual_contrast(&gt, &gt, &mask), None);
}
