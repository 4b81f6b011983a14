//! Dataset loaders on hand-made fixtures: Blender layout (RGBA compositing,
//! camera conversion, normals in .npy/.png/.exr, masks, downscale) and
//! COLMAP text and binary models (pinhole conventions, the every-8th split),
//! and every bad input stopping with an error that names the file.
//!
//! Longer than 500 lines on purpose: one test binary for every loader (each
//! binary is linked separately, and links are a large part of CI's build);
//! the fixtures are written inline so each case reads as one piece.

use std::path::Path;
use tgs::data::colmap::{parse_cameras_bin, parse_cameras_txt, parse_images_bin, parse_images_txt, parse_points_bin, parse_points_txt};
use tgs::data::image_io::{write_exr, write_npy, ImageF};
use tgs::data::{Dataset, LoadOptions};
use tgs_pipelines::Camera;

fn tmp(name: &str) -> tgs_tests::TempDir {
    tgs_tests::TempDir::created(&format!("data-{name}"))
}

fn png_rgba(path: &Path, w: u32, h: u32, px: [u8; 4]) {
    let bytes: Vec<u8> = (0..w * h).flat_map(|_| px).collect();
    image::save_buffer(path, &bytes, w, h, image::ExtendedColorType::Rgba8).unwrap();
}

fn project(cam: &Camera, p: [f32; 3]) -> [f32; 2] {
    let m = &cam.world_to_view;
    let v: Vec<f32> = (0..3).map(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3]).collect();
    [cam.fx * v[0] / v[2] + cam.cx, cam.fy * v[1] / v[2] + cam.cy]
}

/// A camera at (0, -4, 0) looking at the origin along +y, z up (Blender c2w).
const C2W: &str = "[[1,0,0,0],[0,0,-1,-4],[0,1,0,0],[0,0,0,1]]";

fn blender_fixture(name: &str, w: u32, h: u32) -> tgs_tests::TempDir {
    let d = tmp(name);
    std::fs::create_dir_all(d.join("train")).unwrap();
    std::fs::create_dir_all(d.join("test")).unwrap();
    png_rgba(&d.join("train/a.png"), w, h, [255, 0, 0, 128]);
    png_rgba(&d.join("test/b.png"), w, h, [0, 255, 0, 255]);
    let n = ImageF { width: w, height: h, channels: 3, data: (0..w * h).flat_map(|_| [0.0f32, -1.0, 0.0]).collect() };
    write_npy(&d.join("test/b_normal.npy"), &n).unwrap();
    image::save_buffer(d.join("test/b_mask.png"), &vec![255u8; (w * h) as usize], w, h, image::ExtendedColorType::L8).unwrap();
    std::fs::write(d.join("transforms_train.json"), format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "./train/a", "transform_matrix": {C2W}}}]}}"#)).unwrap();
    std::fs::write(
        d.join("transforms_test.json"),
        format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "./test/b", "transform_matrix": {C2W}, "normal_path": "./test/b_normal.npy", "mask_path": "./test/b_mask.png"}}]}}"#),
    )
    .unwrap();
    d
}

#[test]
fn blender_layout_loads_with_conventions_converted() {
    let d = blender_fixture("blender", 8, 6);
    let ds = Dataset::load(&d, &LoadOptions { background: [0.0, 0.0, 1.0], ..Default::default() }).unwrap();
    assert_eq!((ds.train.len(), ds.test.len(), ds.format), (1, 1, "blender"));
    let v = &ds.train[0];
    // 50% red over a blue background.
    let px = &v.image.data[..3];
    assert!((px[0] - 128.0 / 255.0).abs() < 1e-6 && px[1] == 0.0 && (px[2] - 127.0 / 255.0).abs() < 0.01, "composited pixel {px:?}");
    // The world origin is straight ahead: at the principal point (image centre).
    let c = v.camera;
    let p = project(&c, [0.0, 0.0, 0.0]);
    assert!((p[0] - 3.5).abs() < 1e-5 && (p[1] - 2.5).abs() < 1e-5, "origin projects to {p:?}");
    // World +z is up: above the centre in the image (smaller y); +x is right.
    assert!(project(&c, [0.0, 0.0, 0.5])[1] < 2.5 && project(&c, [0.5, 0.0, 0.0])[0] > 3.5);
    assert!((c.fx - 0.5 * 8.0 / (0.4f32).tan()).abs() < 1e-4);
    let t = &ds.test[0];
    assert_eq!(t.normals.as_ref().unwrap().data[..3], [0.0, -1.0, 0.0]);
    assert!(t.mask.as_ref().unwrap().iter().all(|&m| m));
    // Downscale by 2: sizes halve, the origin still projects to the new centre.
    let ds2 = Dataset::load(&d, &LoadOptions { downscale: 2, ..Default::default() }).unwrap();
    let c2 = ds2.train[0].camera;
    assert_eq!((c2.width, c2.height, ds2.train[0].image.width), (4, 3, 4));
    let p = project(&c2, [0.0, 0.0, 0.0]);
    assert!((p[0] - 1.5).abs() < 1e-5 && (p[1] - 1.0).abs() < 1e-5, "downscaled origin at {p:?}");
}

#[test]
fn normals_read_from_npy_png_and_exr_alike() {
    let d = tmp("normals");
    let img = ImageF { width: 3, height: 2, channels: 3, data: vec![0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0] };
    write_npy(&d.join("n.npy"), &img).unwrap();
    write_exr(&d.join("n.exr"), &img).unwrap();
    let png: Vec<u8> = img.data.iter().map(|v| ((v + 1.0) * 0.5 * 255.0).round() as u8).collect();
    image::save_buffer(d.join("n_normal.png"), &png, 3, 2, image::ExtendedColorType::Rgb8).unwrap();
    for f in ["n.npy", "n.exr", "n_normal.png"] {
        let r = tgs::data::image_io::read_normals(&d.join(f)).unwrap();
        assert_eq!((r.width, r.height), (3, 2), "{f}");
        for (a, b) in r.data.iter().zip(&img.data) {
            assert!((a - b).abs() < 0.01, "{f}: {a} vs {b}");
        }
    }
}

fn expect_err(r: anyhow::Result<Dataset>, needles: &[&str]) {
    let e = format!("{:#}", r.expect_err("loading should fail"));
    for n in needles {
        assert!(e.contains(n), "error '{e}' should mention '{n}'");
    }
}

#[test]
fn blender_bad_inputs_name_the_file() {
    let opts = LoadOptions::default();
    let d = blender_fixture("missing", 4, 4);
    std::fs::remove_file(d.join("train/a.png")).unwrap();
    expect_err(Dataset::load(&d, &opts), &["a.png"]);

    let d = blender_fixture("corrupt", 4, 4);
    std::fs::write(d.join("train/a.png"), b"not a png at all").unwrap();
    expect_err(Dataset::load(&d, &opts), &["a.png", "cannot read"]);

    let d = blender_fixture("nonfinite", 4, 4);
    std::fs::write(
        d.join("transforms_train.json"),
        r#"{"camera_angle_x": 0.8, "frames": [{"file_path": "./train/a", "transform_matrix": [[1,0,0,0],[0,0,-1,1e999],[0,1,0,0],[0,0,0,1]]}]}"#,
    )
    .unwrap();
    expect_err(Dataset::load(&d, &opts), &["transforms_train.json"]);

    let d = blender_fixture("notfour", 4, 4);
    std::fs::write(d.join("transforms_train.json"), r#"{"camera_angle_x": 0.8, "frames": [{"file_path": "./train/a", "transform_matrix": [[1,0,0],[0,1,0],[0,0,1]]}]}"#).unwrap();
    expect_err(Dataset::load(&d, &opts), &["transforms_train.json", "4x4"]);

    let d = blender_fixture("mask", 4, 4);
    image::save_buffer(d.join("test/b_mask.png"), &[255u8; 6], 3, 2, image::ExtendedColorType::L8).unwrap();
    expect_err(Dataset::load(&d, &opts), &["b_mask.png", "3x2", "4x4"]);

    let d = blender_fixture("normalsize", 4, 4);
    write_npy(&d.join("test/b_normal.npy"), &ImageF::new(5, 4, 3)).unwrap();
    expect_err(Dataset::load(&d, &opts), &["b_normal.npy", "5x4"]);

    let d = blender_fixture("badnpy", 4, 4);
    std::fs::write(d.join("test/b_normal.npy"), b"\x93NUMPY\x01\x00\x10\x00{'descr': '<i4'}").unwrap();
    expect_err(Dataset::load(&d, &opts), &["b_normal.npy"]);

    let d = blender_fixture("empty", 4, 4);
    std::fs::write(d.join("transforms_train.json"), r#"{"camera_angle_x": 0.8, "frames": []}"#).unwrap();
    expect_err(Dataset::load(&d, &opts), &["transforms_train.json", "no frames"]);

    let d = blender_fixture("nofov", 4, 4);
    std::fs::write(d.join("transforms_train.json"), format!(r#"{{"frames": [{{"file_path": "./train/a", "transform_matrix": {C2W}}}]}}"#)).unwrap();
    expect_err(Dataset::load(&d, &opts), &["camera_angle_x"]);

    expect_err(Dataset::load(Path::new("/nonexistent/tgs-dataset"), &opts), &["/nonexistent/tgs-dataset"]);
    let d = tmp("neither");
    expect_err(Dataset::load(&d, &opts), &["transforms_train.json", "sparse"]);
}

// ---- COLMAP ----

struct Img {
    name: &'static str,
    q: [f64; 4],
    t: [f64; 3],
    cam: u32,
}

fn images() -> Vec<Img> {
    // Nine images (names deliberately unsorted): identity rotation, cameras at z = -4 - i/10.
    (0..9)
        .map(|i| Img {
            name: ["c.png", "a.png", "i.png", "b.png", "h.png", "d.png", "g.png", "e.png", "f.png"][i],
            q: [1.0, 0.0, 0.0, 0.0],
            t: [0.0, 0.0, 4.0 + i as f64 / 10.0],
            cam: 1 + (i % 2) as u32,
        })
        .collect()
}

fn write_text_model(dir: &Path, model2: &str) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("cameras.txt"), format!("# Camera list\n1 PINHOLE 8 6 10 11 4 3\n2 {model2}\n")).unwrap();
    let mut s = String::from("# Image list\n");
    for (i, im) in images().iter().enumerate() {
        s += &format!("{} {} {} {} {} {} {} {} {} {}\n", i + 1, im.q[0], im.q[1], im.q[2], im.q[3], im.t[0], im.t[1], im.t[2], im.cam, im.name);
        s += "1.0 2.0 -1\n";
    }
    std::fs::write(dir.join("images.txt"), s).unwrap();
    std::fs::write(dir.join("points3D.txt"), "# points\n1 0.5 0.25 1 255 128 0 0.1 1 0\n2 -1 0 0.5 0 0 255 0.2\n").unwrap();
}

fn write_binary_model(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let mut c = Vec::new();
    c.extend(2u64.to_le_bytes());
    for (id, model, params) in [(1i32, 1i32, vec![10.0f64, 11.0, 4.0, 3.0]), (2, 0, vec![9.0, 4.0, 3.0])] {
        c.extend(id.to_le_bytes());
        c.extend(model.to_le_bytes());
        c.extend(8u64.to_le_bytes());
        c.extend(6u64.to_le_bytes());
        params.iter().for_each(|p| c.extend(p.to_le_bytes()));
    }
    std::fs::write(dir.join("cameras.bin"), c).unwrap();
    let mut b = Vec::new();
    b.extend((images().len() as u64).to_le_bytes());
    for (i, im) in images().iter().enumerate() {
        b.extend((i as i32 + 1).to_le_bytes());
        im.q.iter().chain(&im.t).for_each(|v| b.extend(v.to_le_bytes()));
        b.extend((im.cam as i32).to_le_bytes());
        b.extend(im.name.as_bytes());
        b.push(0);
        b.extend(1u64.to_le_bytes());
        b.extend(1.0f64.to_le_bytes());
        b.extend(2.0f64.to_le_bytes());
        b.extend((-1i64).to_le_bytes());
    }
    std::fs::write(dir.join("images.bin"), b).unwrap();
    let mut p = Vec::new();
    p.extend(2u64.to_le_bytes());
    for (id, xyz, rgb, track) in [(1u64, [0.5f64, 0.25, 1.0], [255u8, 128, 0], 1u64), (2, [-1.0, 0.0, 0.5], [0, 0, 255], 0)] {
        p.extend(id.to_le_bytes());
        xyz.iter().for_each(|v| p.extend(v.to_le_bytes()));
        p.extend(rgb);
        p.extend(0.1f64.to_le_bytes());
        p.extend(track.to_le_bytes());
        for _ in 0..track {
            p.extend(1i32.to_le_bytes());
            p.extend(0i32.to_le_bytes());
        }
    }
    std::fs::write(dir.join("points3D.bin"), p).unwrap();
}

fn colmap_fixture(name: &str, binary: bool) -> tgs_tests::TempDir {
    let d = tmp(name);
    std::fs::create_dir_all(d.join("images")).unwrap();
    for im in images() {
        png_rgba(&d.join("images").join(im.name), 8, 6, [10, 20, 30, 255]);
    }
    if binary {
        write_binary_model(&d.join("sparse/0"));
    } else {
        write_text_model(&d.join("sparse/0"), "SIMPLE_PINHOLE 8 6 9 4 3");
    }
    d
}

#[test]
fn colmap_text_and_binary_agree() {
    let t = colmap_fixture("colmap-txt", false);
    let b = colmap_fixture("colmap-bin", true);
    let dir = |d: &Path| d.join("sparse/0");
    assert_eq!(
        parse_cameras_txt(&std::fs::read_to_string(dir(&t).join("cameras.txt")).unwrap()).unwrap(),
        parse_cameras_bin(&std::fs::read(dir(&b).join("cameras.bin")).unwrap()).unwrap()
    );
    assert_eq!(
        parse_images_txt(&std::fs::read_to_string(dir(&t).join("images.txt")).unwrap()).unwrap(),
        parse_images_bin(&std::fs::read(dir(&b).join("images.bin")).unwrap()).unwrap()
    );
    let (pt, pb) = (
        parse_points_txt(&std::fs::read_to_string(dir(&t).join("points3D.txt")).unwrap()).unwrap().0,
        parse_points_bin(&std::fs::read(dir(&b).join("points3D.bin")).unwrap()).unwrap().0,
    );
    assert_eq!((pt.positions.clone(), pt.colors.clone()), (pb.positions, pb.colors));
    assert_eq!(pt.positions, vec![[0.5, 0.25, 1.0], [-1.0, 0.0, 0.5]]);

    for d in [&t, &b] {
        let ds = Dataset::load(d, &LoadOptions::default()).unwrap();
        assert_eq!(ds.format, "colmap");
        // Sorted by name a..i; every 8th (a, i) is a test image.
        let names = |v: &[tgs::data::View]| v.iter().map(|x| x.name.clone()).collect::<Vec<_>>();
        assert_eq!(names(&ds.test), ["a.png", "i.png"]);
        assert_eq!(names(&ds.train), ["b.png", "c.png", "d.png", "e.png", "f.png", "g.png", "h.png"]);
        // c.png (image 0) has the PINHOLE camera fx 10 fy 11 cx 4 cy 3; COLMAP puts pixel 0's centre at 0.5.
        let c = ds.train[1].camera;
        assert_eq!((c.fx, c.fy, c.cx, c.cy), (10.0, 11.0, 3.5, 2.5));
        let p = project(&c, [0.0, 0.0, 0.0]);
        assert!((p[0] - 3.5).abs() < 1e-6 && (p[1] - 2.5).abs() < 1e-6);
        // a.png (image 1) has the SIMPLE_PINHOLE camera f 9 cx 4 cy 3.
        let c = ds.test[0].camera;
        assert_eq!((c.fx, c.fy, c.cx, c.cy), (9.0, 9.0, 3.5, 2.5));
        assert_eq!(ds.points.as_ref().unwrap().positions.len(), 2);
        let ds2 = Dataset::load(d, &LoadOptions { downscale: 2, ..Default::default() }).unwrap();
        let c2 = ds2.test[0].camera;
        assert_eq!((c2.width, c2.height, c2.fx, c2.cx), (4, 3, 4.5, 1.5));
    }
}

#[test]
fn colmap_bad_inputs_name_the_problem() {
    let opts = LoadOptions::default();
    let d = colmap_fixture("colmap-model", false);
    write_text_model(&d.join("sparse/0"), "OPENCV 8 6 9 9 4 3 0.1 0.01 0 0");
    expect_err(Dataset::load(&d, &opts), &["OPENCV", "PINHOLE"]);

    let d = colmap_fixture("colmap-trunc", true);
    let b = std::fs::read(d.join("sparse/0/images.bin")).unwrap();
    std::fs::write(d.join("sparse/0/images.bin"), &b[..b.len() - 20]).unwrap();
    expect_err(Dataset::load(&d, &opts), &["images.bin", "truncated"]);

    let d = colmap_fixture("colmap-count", true);
    let mut b = std::fs::read(d.join("sparse/0/cameras.bin")).unwrap();
    b[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    std::fs::write(d.join("sparse/0/cameras.bin"), b).unwrap();
    expect_err(Dataset::load(&d, &opts), &["cameras.bin"]);

    let d = colmap_fixture("colmap-missing", false);
    std::fs::remove_file(d.join("images/e.png")).unwrap();
    expect_err(Dataset::load(&d, &opts), &["e.png"]);

    let d = colmap_fixture("colmap-size", false);
    png_rgba(&d.join("images/e.png"), 7, 6, [0, 0, 0, 255]);
    expect_err(Dataset::load(&d, &opts), &["e.png", "7x6", "8x6"]);

    let d = colmap_fixture("colmap-text", false);
    std::fs::write(d.join("sparse/0/cameras.txt"), "1 PINHOLE 8 six 10 11 4 3\n").unwrap();
    expect_err(Dataset::load(&d, &opts), &["cameras.txt", "line 1", "six"]);

    let d = colmap_fixture("colmap-quat", false);
    let t = std::fs::read_to_string(d.join("sparse/0/images.txt")).unwrap().replacen("1 1 0 0 0", "1 0 0 0 0", 1);
    std::fs::write(d.join("sparse/0/images.txt"), t).unwrap();
    expect_err(Dataset::load(&d, &opts), &["c.png", "quaternion"]);

    let d = colmap_fixture("colmap-cam", false);
    let t = std::fs::read_to_string(d.join("sparse/0/images.txt")).unwrap().replacen(" 1 c.png", " 7 c.png", 1);
    std::fs::write(d.join("sparse/0/images.txt"), t).unwrap();
    expect_err(Dataset::load(&d, &opts), &["c.png", "camera 7"]);
}

#[test]
fn shared_lantern_dataset_loads() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/lantern");
    if !root.is_dir() {
        eprintln!("skipping: {} not present", root.display());
        return;
    }
    let ds = Dataset::load(&root, &LoadOptions::default()).unwrap();
    assert_eq!((ds.train.len(), ds.test.len()), (60, 12));
    assert!(ds.test.iter().all(|v| v.normals.is_some() && v.mask.is_some() && v.image.width == 200));
}

/// Inputs that used to panic or load silently: each is refused with the file,
/// the frame or the option named.
#[test]
fn hostile_inputs_are_refused_not_trained() {
    let opts = LoadOptions::default();
    // A vertex count whose byte size wraps usize (it panicked in ply.rs).
    let d = blender_fixture("ply-count", 4, 4);
    let ply = "ply\nformat binary_little_endian 1.0\nelement vertex 1229782938247303442\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    std::fs::write(d.join("points3d.ply"), [ply.as_bytes(), &[0u8; 24]].concat()).unwrap();
    expect_err(Dataset::load(&d, &opts), &["points3d.ply", "1229782938247303442"]);
    assert!(tgs::export::ply::read_splats(&d.join("points3d.ply")).is_err());

    // Camera-to-world matrices that are not rigid motions: named by frame.
    for (name, m) in [
        ("zeros", "[[0,0,0,0],[0,0,0,0],[0,0,0,0],[0,0,0,0]]"),
        ("singular", "[[1,0,0,0],[0,0,0,-4],[0,1,0,0],[0,0,0,1]]"),
        ("rank2", "[[1,0,0,0],[0,1,0,-4],[0,1,0,0],[0,0,0,1]]"),
        ("scaled", "[[2,0,0,0],[0,0,-2,-4],[0,2,0,0],[0,0,0,1]]"),
        ("mirrored", "[[-1,0,0,0],[0,0,-1,-4],[0,1,0,0],[0,0,0,1]]"),
        ("projective", "[[1,0,0,0],[0,0,-1,-4],[0,1,0,0],[0,0.5,0,1]]"),
    ] {
        let d = blender_fixture(&format!("pose-{name}"), 4, 4);
        std::fs::write(d.join("transforms_train.json"), format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "./train/a", "transform_matrix": {m}}}]}}"#)).unwrap();
        expect_err(Dataset::load(&d, &opts), &["transforms_train.json", "frame 0", "./train/a", "transform_matrix"]);
    }
    // Python's json.dump writes NaN and Infinity as bare words.
    for (word, shown) in [("NaN", "NaN"), ("Infinity", "Infinity"), ("-Infinity", "-Infinity")] {
        let d = blender_fixture(&format!("nan{shown}"), 4, 4);
        std::fs::write(
            d.join("transforms_train.json"),
            format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "./train/a", "transform_matrix": [[1,0,0,0],[0,0,-1,{word}],[0,1,0,0],[0,0,0,1]]}}]}}"#),
        )
        .unwrap();
        expect_err(Dataset::load(&d, &opts), &["transforms_train.json", "frame 0", "transform_matrix[1][3]", shown]);
    }
    let d = blender_fixture("nan-fov", 4, 4);
    std::fs::write(d.join("transforms_train.json"), format!(r#"{{"camera_angle_x": NaN, "frames": [{{"file_path": "./train/a", "transform_matrix": {C2W}}}]}}"#)).unwrap();
    expect_err(Dataset::load(&d, &opts), &["transforms_train.json", "camera_angle_x", "NaN"]);
    // A string containing the word is still a string (a file name here).
    let d = blender_fixture("nan-name", 4, 4);
    std::fs::rename(d.join("train/a.png"), d.join("train/NaN.png")).unwrap();
    std::fs::write(d.join("transforms_train.json"), format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "./train/NaN", "transform_matrix": {C2W}}}]}}"#)).unwrap();
    assert_eq!(Dataset::load(&d, &opts).unwrap().train[0].name, "NaN");

    // A downscale that leaves nothing names the option and the image.
    let d = blender_fixture("downscale", 4, 4);
    expect_err(Dataset::load(&d, &LoadOptions { downscale: 1000, ..opts }), &["--downscale 1000", "a.png"]);
    let c = colmap_fixture("colmap-downscale", false);
    expect_err(Dataset::load(&c, &LoadOptions { downscale: 1000, ..opts }), &["--downscale 1000", ".png"]);

    // images.txt without the (possibly empty) 2-D points lines would load
    // every second image: detected.
    let c = colmap_fixture("colmap-nopoints", false);
    let t: String = std::fs::read_to_string(c.join("sparse/0/images.txt")).unwrap().lines().filter(|l| *l != "1.0 2.0 -1").map(|l| format!("{l}\n")).collect();
    std::fs::write(c.join("sparse/0/images.txt"), t).unwrap();
    expect_err(Dataset::load(&c, &opts), &["images.txt", "line 3", "2-D points"]);
    // Empty points lines are fine.
    let c = colmap_fixture("colmap-emptypoints", false);
    let t = std::fs::read_to_string(c.join("sparse/0/images.txt")).unwrap().replace("1.0 2.0 -1\n", "\n");
    std::fs::write(c.join("sparse/0/images.txt"), t).unwrap();
    let ds = Dataset::load(&c, &opts).unwrap();
    assert_eq!(ds.train.len() + ds.test.len(), 9);

    // A .npy shape whose byte size wraps.
    let d = blender_fixture("npy-shape", 4, 4);
    let header = "{'descr': '<f4', 'fortran_order': False, 'shape': (4294967296, 4294967296, 3), }";
    let mut npy = b"\x93NUMPY\x01\x00".to_vec();
    npy.extend((header.len() as u16).to_le_bytes());
    npy.extend(header.as_bytes());
    npy.extend([0u8; 64]);
    std::fs::write(d.join("test/b_normal.npy"), npy).unwrap();
    expect_err(Dataset::load(&d, &opts), &["b_normal.npy", "too large"]);
}

#[test]
fn scene_make_never_overwrites() {
    let spec = tgs::scene::spec("glass-tiny").unwrap();
    let d = tmp("scene-nonempty");
    std::fs::write(d.join("keep.txt"), "mine").unwrap();
    let e = format!("{:#}", tgs::scene::make(&spec, &d, |_, _| {}).unwrap_err());
    assert!(e.contains("not empty") && e.contains("scene-nonempty"), "{e}");
    assert_eq!(std::fs::read_to_string(d.join("keep.txt")).unwrap(), "mine");
    assert_eq!(std::fs::read_dir(&d).unwrap().count(), 1);
    // An existing empty directory is fine, and no partial directory is left.
    let d = tmp("scene-empty");
    tgs::scene::make(&spec, &d, |_, _| {}).unwrap();
    assert!(d.join("transforms_train.json").is_file() && d.join("points3d.ply").is_file());
    assert!(!d.with_file_name(format!("{}.tgs-partial", d.file_name().unwrap().to_string_lossy())).exists());
}

/// Brush's workload, ported: the written dataset loads, looks at the
/// origin, has coloured spheres on black and the requested points; the
/// in-memory dataset is the same.
#[test]
fn spheres_scene_is_brushs_workload() {
    let d = tmp("spheres");
    std::fs::remove_dir(&d).unwrap();
    tgs::scene::make_named("spheres-128", &d, |_, _| {}).unwrap();
    let ds = Dataset::load(&d, &LoadOptions { background: [0.0; 3], ..Default::default() }).unwrap();
    assert_eq!((ds.train.len(), ds.test.len()), (20, 4));
    assert_eq!(ds.points.as_ref().unwrap().positions.len(), 10_000);
    let mem = tgs::scene::spheres::dataset(&tgs::scene::spheres::SpheresSpec::named("spheres-128").unwrap()).unwrap();
    for (a, b) in ds.train.iter().zip(&mem.train) {
        assert_eq!((a.camera.width, a.camera.height), (128, 128));
        // The PNG is 8-bit: the same image to within quantisation.
        assert!(a.image.data.iter().zip(&b.image.data).all(|(x, y)| (x - y).abs() <= 0.5 / 255.0 + 1e-6));
        for k in 0..3 {
            for j in 0..4 {
                assert!((a.camera.world_to_view[k][j] - b.camera.world_to_view[k][j]).abs() < 1e-5);
            }
        }
        // The origin (the big sphere's centre) is at the image centre, in front.
        let p = project(&a.camera, [0.0, 0.0, 0.0]);
        assert!((p[0] - 63.5).abs() < 1e-3 && (p[1] - 63.5).abs() < 1e-3, "{p:?}");
        let lit = a.image.data.chunks(3).filter(|c| c.iter().any(|&v| v > 0.05)).count();
        let black = a.image.data.chunks(3).filter(|c| c.iter().all(|&v| v == 0.0)).count();
        assert!(lit > 128 * 128 / 10 && black > 128 * 128 / 10, "{lit} lit and {black} black pixels");
    }
    // Points lie on the spheres (the first has radius 0.55 at the origin).
    let pts = &mem.points.as_ref().unwrap().positions;
    let on_first = pts.iter().filter(|p| ((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 0.55).abs() < 1e-4).count();
    assert!(on_first > pts.len() / 4 && on_first < pts.len() / 2, "{on_first} of {} on the centre sphere", pts.len());
    assert!(tgs::scene::make_named("spheres-128", &d, |_, _| {}).is_err(), "overwrote a dataset");
    assert!(format!("{:#}", tgs::scene::make_named("cubes", &tmp("cubes"), |_, _| {}).unwrap_err()).contains("spheres-256"));
}

/// The built-in `diffuse` scene is the glass scene's room without the glass
/// sphere: rays at the sphere meet diffuse surfaces behind it, the images
/// differ from the glass scene only there, and no test pixel is glass.
#[test]
fn diffuse_scene_is_the_glass_room_without_glass() {
    use tgs::scene::trace::{Material, Scene, GLASS_C, V3};
    let glass = Scene::new();
    let mut diffuse = Scene::new();
    diffuse.glass = false;
    let e = V3::new(2.7, 0.0, 1.15);
    let d = (GLASS_C - e).normalize();
    assert!(glass.intersect(e, d, f64::INFINITY, true).is_some_and(|h| h.mat == Material::Glass));
    assert!(diffuse.intersect(e, d, f64::INFINITY, true).is_some_and(|h| h.mat != Material::Glass));
    assert_ne!(glass.radiance(e, d, 6), diffuse.radiance(e, d, 6));
    // A ray that misses the sphere (the floor beside it) sees the same.
    let d2 = (V3::new(0.0, 1.6, 0.0) - e).normalize();
    assert_eq!(glass.radiance(e, d2, 6), diffuse.radiance(e, d2, 6));
    let spec = tgs::scene::spec("diffuse").unwrap();
    assert!(!spec.glass && spec.size == tgs::scene::spec("glass").unwrap().size);
    let dir = tmp("diffuse-scene");
    tgs::scene::make(&tgs::scene::SceneSpec { train: 2, test: 2, points: 100, ..spec }, &dir, |_, _| {}).unwrap();
    let ds = Dataset::load(&dir, &LoadOptions::default()).unwrap();
    assert!(ds.test.iter().all(|v| v.mask.as_ref().is_some_and(|m| m.iter().all(|&g| !g))), "a glass pixel in the diffuse scene");
}

/// Inputs that loaded silently before and trained on nonsense.
#[test]
fn accepted_nonsense_is_refused_or_warned_about() {
    let opts = LoadOptions::default();
    // A focal length of 4.8e31 px (camera_angle_x = 1e-30).
    let d = blender_fixture("tinyfov", 4, 4);
    std::fs::write(d.join("transforms_train.json"), format!(r#"{{"camera_angle_x": 1e-30, "frames": [{{"file_path": "./train/a", "transform_matrix": {C2W}}}]}}"#)).unwrap();
    expect_err(Dataset::load(&d, &opts), &["transforms_train.json", "field of view", "camera_angle_x"]);
    // A long lens still loads (focal length 1,000 image widths).
    std::fs::write(d.join("transforms_train.json"), format!(r#"{{"fl_x": 4000, "frames": [{{"file_path": "./train/a", "transform_matrix": {C2W}}}]}}"#)).unwrap();
    Dataset::load(&d, &opts).unwrap();

    // One image twice in a split, and one image with two poses across the splits.
    let d = blender_fixture("dupframe", 4, 4);
    let two = r#"[[1,0,0,0],[0,0,-1,-5],[0,1,0,0],[0,0,0,1]]"#;
    std::fs::write(
        d.join("transforms_train.json"),
        format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "./train/a", "transform_matrix": {C2W}}}, {{"file_path": "./train/a", "transform_matrix": {two}}}]}}"#),
    )
    .unwrap();
    expect_err(Dataset::load(&d, &opts), &["transforms_train.json", "./train/a", "twice", "frames 0 and 1"]);
    let d = blender_fixture("twoposes", 4, 4);
    std::fs::write(d.join("transforms_test.json"), format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "./train/a", "transform_matrix": {two}}}]}}"#)).unwrap();
    expect_err(Dataset::load(&d, &opts), &["train/a", "two different poses"]);

    // Paths that leave the dataset directory.
    for bad in ["../outside/a", "/etc/passwd", "train/../../a"] {
        let d = blender_fixture("escape", 4, 4);
        std::fs::write(d.join("transforms_train.json"), format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "{bad}", "transform_matrix": {C2W}}}]}}"#)).unwrap();
        expect_err(Dataset::load(&d, &opts), &[bad, "dataset directory"]);
    }
    // Inside it, `..` that stays inside is fine.
    let d = blender_fixture("inside", 4, 4);
    std::fs::write(d.join("transforms_train.json"), format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "./test/../train/a", "transform_matrix": {C2W}}}]}}"#)).unwrap();
    Dataset::load(&d, &opts).unwrap();

    // NaN and infinite points: skipped, and said.
    let d = blender_fixture("nanpoints", 4, 4);
    std::fs::write(d.join("points3d.ply"), "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n").unwrap();
    let mut b = std::fs::read(d.join("points3d.ply")).unwrap();
    let ply_head = String::from_utf8(b.clone()).unwrap().replace("ascii", "binary_little_endian");
    b = ply_head.into_bytes();
    for p in [[0.0f32, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, f32::INFINITY, 1.0]] {
        p.iter().for_each(|v| b.extend(v.to_le_bytes()));
    }
    std::fs::write(d.join("points3d.ply"), &b).unwrap();
    let ds = Dataset::load(&d, &opts).unwrap();
    assert_eq!(ds.points.as_ref().unwrap().positions.len(), 1);
    assert!(ds.warnings.iter().any(|w| w.contains("points3d.ply") && w.contains("2 of 3 points")), "{:?}", ds.warnings);

    // RGB images on a flat black backdrop against the white default: said,
    // with the option that fixes it; on black, nothing is said.
    let d = blender_fixture("backdrop", 6, 6);
    let mut px = vec![0u8; 6 * 6 * 3];
    px[3 * (2 * 6 + 2)..3 * (2 * 6 + 4)].fill(200);
    image::save_buffer(d.join("train/a.png"), &px, 6, 6, image::ExtendedColorType::Rgb8).unwrap();
    let ds = Dataset::load(&d, &opts).unwrap();
    assert!(ds.warnings.iter().any(|w| w.contains("--background 0.00,0.00,0.00") && w.contains("no alpha")), "{:?}", ds.warnings);
    let ds = Dataset::load(&d, &LoadOptions { background: [0.0; 3], ..opts }).unwrap();
    assert!(ds.warnings.is_empty(), "{:?}", ds.warnings);
    // RGBA images (the fixture's own) are composited: nothing to say.
    assert!(Dataset::load(&blender_fixture("rgba", 4, 4), &opts).unwrap().warnings.is_empty());

    // COLMAP: an image twice in the model, and a model without cameras.
    let d = colmap_fixture("colmap-dup", false);
    let t = std::fs::read_to_string(d.join("sparse/0/images.txt")).unwrap().replacen(" a.png", " c.png", 1);
    std::fs::write(d.join("sparse/0/images.txt"), t).unwrap();
    expect_err(Dataset::load(&d, &opts), &["c.png", "twice"]);
    let d = colmap_fixture("colmap-nocams", false);
    std::fs::remove_file(d.join("sparse/0/cameras.txt")).unwrap();
    expect_err(Dataset::load(&d, &opts), &["sparse/0", "cameras.txt"]);
    // A COLMAP focal length of 10^6 image widths.
    let d = colmap_fixture("colmap-fov", false);
    write_text_model(&d.join("sparse/0"), "SIMPLE_PINHOLE 8 6 9e6 4 3");
    expect_err(Dataset::load(&d, &opts), &["field of view"]);
}

#[test]
fn scene_list_says_what_each_scene_is() {
    let lines = tgs::scene::list();
    let diffuse = lines.iter().find(|l| l.starts_with("diffuse")).unwrap();
    assert!(!diffuse.contains("glass sphere in") && diffuse.contains("without the glass"), "{diffuse}");
    assert!(lines.iter().find(|l| l.starts_with("glass ")).unwrap().contains("glass sphere"));
}

/// A JPEG of `w` x `h` (RGB, or grey when `grey`), quality 100, pixel (x, y)
/// = `f(x, y)`; returns what the file decodes to (RGB in [0, 1]).
fn jpeg(path: &Path, w: u32, h: u32, grey: bool, f: impl Fn(u32, u32) -> [u8; 3]) -> Vec<f32> {
    let rgb: Vec<u8> = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).flat_map(|(x, y)| f(x, y)).collect();
    let file = std::fs::File::create(path).unwrap();
    let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(file, 100);
    if grey {
        let l: Vec<u8> = rgb.chunks(3).map(|p| p[0]).collect();
        enc.encode(&l, w, h, image::ExtendedColorType::L8).unwrap();
    } else {
        enc.encode(&rgb, w, h, image::ExtendedColorType::Rgb8).unwrap();
    }
    image::open(path).unwrap().to_rgb32f().into_raw()
}

/// Real captures are JPEG (Mip-NeRF 360, the NeRF-Casting scenes): a COLMAP
/// model whose images are `.JPG` and `.jpg`, one of them grey, with a
/// prescaled `images_2/` that `--downscale 2` reads; and a Blender frame
/// whose `file_path` names a JPEG.
#[test]
fn jpeg_captures_load_in_both_layouts() {
    let d = tmp("colmap-jpeg");
    let model = d.join("sparse/0");
    std::fs::create_dir_all(&model).unwrap();
    std::fs::create_dir_all(d.join("images")).unwrap();
    std::fs::create_dir_all(d.join("images_2")).unwrap();
    std::fs::write(model.join("cameras.txt"), "1 PINHOLE 16 12 20 20 8 6\n").unwrap();
    let names = ["IMG_0001.JPG", "IMG_0002.jpg", "IMG_0003.JPG"];
    let mut text = String::new();
    let mut full = Vec::new();
    let mut half = Vec::new();
    for (i, name) in names.iter().enumerate() {
        text += &format!("{} 1 0 0 0 0 0 {} 1 {name}\n\n", i + 1, 4.0 + i as f64);
        let grey = i == 2;
        full.push(jpeg(&d.join("images").join(name), 16, 12, grey, |x, y| [(x * 15) as u8, (y * 20) as u8, 100 + 10 * i as u8]));
        // The prescaled copy differs from a box filter of the full one, so
        // the test sees which was read.
        half.push(jpeg(&d.join("images_2").join(name), 8, 6, grey, |_, _| [200, 40 + 50 * i as u8, 90]));
    }
    std::fs::write(model.join("images.txt"), text).unwrap();
    std::fs::write(model.join("points3D.txt"), "1 0 0 1 255 255 255 0.1\n").unwrap();

    let ds = Dataset::load(&d, &LoadOptions { holdout: 0, ..Default::default() }).unwrap();
    assert_eq!(ds.format, "colmap");
    assert_eq!(ds.train.iter().map(|v| v.name.as_str()).collect::<Vec<_>>(), names);
    for (v, want) in ds.train.iter().zip(&full) {
        assert_eq!((v.image.width, v.image.height, v.image.channels), (16, 12, 3), "{}", v.name);
        assert_eq!(&v.image.data, want, "{}: pixels differ from the decoded JPEG", v.name);
    }
    // The encoder's loss is small: the gradient survives.
    let px = |v: &tgs::data::View, x: usize, y: usize| v.image.data[(y * 16 + x) * 3];
    assert!((px(&ds.train[0], 10, 0) - 150.0 / 255.0).abs() < 0.03 && px(&ds.train[0], 0, 0) < 0.03);
    // The grey JPEG loads as RGB with three equal channels.
    assert!(ds.train[2].image.data.chunks(3).all(|p| p[0] == p[1] && p[1] == p[2]));
    // --downscale 2 reads images_2/ as it is (the camera at half size).
    let ds2 = Dataset::load(&d, &LoadOptions { holdout: 0, downscale: 2, ..Default::default() }).unwrap();
    for (v, want) in ds2.train.iter().zip(&half) {
        assert_eq!((v.camera.width, v.camera.height, v.image.width), (8, 6, 8), "{}", v.name);
        assert_eq!(&v.image.data, want, "{}: not the prescaled JPEG", v.name);
    }
    // Without images_2/, the full JPEGs are box-filtered.
    std::fs::remove_dir_all(d.join("images_2")).unwrap();
    let ds3 = Dataset::load(&d, &LoadOptions { holdout: 0, downscale: 2, ..Default::default() }).unwrap();
    assert_eq!(ds3.train[0].image.width, 8);
    let box00: f32 = [(0, 0), (1, 0), (0, 1), (1, 1)].iter().map(|&(x, y)| full[0][(y * 16 + x) * 3 + 2]).sum::<f32>() / 4.0;
    assert!((ds3.train[0].image.data[2] - box00).abs() < 1e-6);
    // A distorted camera model is refused, saying how to undistort.
    std::fs::write(model.join("cameras.txt"), "1 OPENCV 16 12 20 20 8 6 0.1 0 0 0\n").unwrap();
    expect_err(Dataset::load(&d, &LoadOptions::default()), &["OPENCV", "image_undistorter"]);

    // Blender layout: a frame whose file_path is a JPEG.
    let b = blender_fixture("blender-jpeg", 8, 6);
    let want = jpeg(&b.join("train/a.jpg"), 8, 6, false, |x, _| [(x * 30) as u8, 60, 90]);
    std::fs::remove_file(b.join("train/a.png")).unwrap();
    std::fs::write(b.join("transforms_train.json"), format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "./train/a.jpg", "transform_matrix": {C2W}}}]}}"#)).unwrap();
    let ds = Dataset::load(&b, &LoadOptions::default()).unwrap();
    assert_eq!(ds.train[0].image.data, want);
    // The PNG variants docs/usage.md names: 16-bit RGBA and grey + alpha,
    // composited on the (white) background.
    let rgba16: Vec<u8> = (0..48).flat_map(|_| [0xffffu16, 0x8000, 0, 0x8000]).flat_map(|v| v.to_ne_bytes()).collect();
    image::save_buffer(b.join("train/a.png"), &rgba16, 8, 6, image::ExtendedColorType::Rgba16).unwrap();
    let frame =
        |f: &str| std::fs::write(b.join("transforms_train.json"), format!(r#"{{"camera_angle_x": 0.8, "frames": [{{"file_path": "{f}", "transform_matrix": {C2W}}}]}}"#)).unwrap();
    frame("./train/a");
    let px = Dataset::load(&b, &LoadOptions::default()).unwrap().train[0].image.data[..3].to_vec();
    let a = 0x8000 as f32 / 65535.0;
    for (k, want) in [1.0, a * a + 1.0 - a, 1.0 - a].iter().enumerate() {
        assert!((px[k] - want).abs() < 1e-4, "16-bit RGBA pixel {px:?}");
    }
    image::save_buffer(b.join("train/a.png"), &[64u8, 255].repeat(48), 8, 6, image::ExtendedColorType::La8).unwrap();
    let px = Dataset::load(&b, &LoadOptions::default()).unwrap().train[0].image.data[..3].to_vec();
    assert!(px.iter().all(|&v| (v - 64.0 / 255.0).abs() < 1e-6), "grey + alpha pixel {px:?}");
}

#[test]
fn colmap_points_skipped_or_few_are_said() {
    // NaN and 1e40 (past f32) were dropped without a word; one point left trained one Gaussian silently.
    let c = colmap_fixture("colmap-badpoints", false);
    std::fs::write(c.join("sparse/0/points3D.txt"), "1 NaN 0 1 255 0 0 0.1\n2 1e40 0 1 0 255 0 0.1\n3 0.5 0.25 1 0 0 255 0.1\n").unwrap();
    let ds = Dataset::load(&c, &LoadOptions::default()).unwrap();
    assert_eq!(ds.points.as_ref().unwrap().positions.len(), 1);
    let w = ds.warnings.join("\n");
    assert!(w.contains("points3D.txt") && w.contains("2 of 3 points have NaN or infinite coordinates") && w.contains("only 1 usable point"), "{w}");
    // Without a points3D file: random points, as before, and nothing to say of a file.
    let c = colmap_fixture("colmap-nopointsfile", false);
    std::fs::remove_file(c.join("sparse/0/points3D.txt")).unwrap();
    let ds = Dataset::load(&c, &LoadOptions::default()).unwrap();
    assert!(ds.points.is_none() && ds.warnings.is_empty(), "{:?}", ds.warnings);
    // A points file that is there but unreadable is an error naming it, not "no points".
    std::fs::write(c.join("sparse/0/points3D.txt"), "1 0 0\n").unwrap();
    expect_err(Dataset::load(&c, &LoadOptions::default()), &["points3D.txt", "corrupt"]);
    std::fs::write(c.join("sparse/0/points3D.txt"), [0xffu8, 0xfe, b'\n']).unwrap();
    expect_err(Dataset::load(&c, &LoadOptions::default()), &["points3D.txt", "UTF-8"]);
    std::fs::remove_file(c.join("sparse/0/points3D.txt")).unwrap();
    std::fs::write(c.join("sparse/0/images.txt"), [0xffu8, 0xfe, b'\n']).unwrap();
    expect_err(Dataset::load(&c, &LoadOptions::default()), &["images.txt", "UTF-8"]);
}
