//! Screenshots and script captures: what the window showed, as an RGB PNG
//! (the same bytes `tgs render` writes for that camera and layer), into a
//! file that did not exist (never over one).

use anyhow::{bail, Context as _, Result};
use std::io::Write as _;
use std::path::{Path, PathBuf};
use tgs_pipelines::PixelOrder;

/// Write `pixels` (packed in `order`, `w` x `h`) as an RGB PNG into `path`,
/// which must not exist.
pub fn write_new(path: &Path, pixels: &[u32], (w, h): (u32, u32), order: PixelOrder) -> Result<()> {
    if pixels.len() != (w * h) as usize {
        bail!("{} pixels for a {w}x{h} image", pixels.len());
    }
    let rgb: Vec<u8> = pixels
        .iter()
        .flat_map(|&p| {
            let b = p.to_le_bytes();
            match order {
                PixelOrder::Rgba => [b[0], b[1], b[2]],
                PixelOrder::Bgra => [b[2], b[1], b[0]],
            }
        })
        .collect();
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png).write_image(&rgb, w, h, image::ExtendedColorType::Rgb8).with_context(|| format!("{}: encoding the PNG", path.display()))?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    }
    let mut f = std::fs::OpenOptions::new().write(true).create_new(true).open(path).with_context(|| {
        if path.exists() {
            format!("{}: exists; tgs view never writes over a file (choose another name)", path.display())
        } else {
            format!("{}: cannot create the file", path.display())
        }
    })?;
    f.write_all(&png).with_context(|| format!("{}: writing the PNG", path.display()))
}

/// A new file in `dir` for a screenshot: `STEM.png`, else `STEM-2.png`, ...
pub fn fresh_name(dir: &Path, stem: &str) -> PathBuf {
    let clean: String = stem.chars().map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '_' }).collect();
    unused_path(dir, &clean, ".png")
}

/// `dir/STEMSUFFIX`, else `dir/STEM-2SUFFIX`, ...: the first that does not exist.
pub fn unused_path(dir: &Path, stem: &str, suffix: &str) -> PathBuf {
    (1..).map(|k| dir.join(if k == 1 { format!("{stem}{suffix}") } else { format!("{stem}-{k}{suffix}") })).find(|p| !p.exists()).expect("an unused name")
}

use image::ImageEncoder as _;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_rgb_in_either_order_and_never_over_a_file() {
        let dir = std::env::temp_dir().join(format!("tgs-view-shot-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let px = [0x11223344u32, 0xff00ff00];
        let a = fresh_name(&dir, "cam 1/final");
        assert_eq!(a, dir.join("cam_1_final.png"));
        write_new(&a, &px, (2, 1), PixelOrder::Bgra).unwrap();
        let img = image::open(&a).unwrap().to_rgb8();
        assert_eq!(img.as_raw(), &vec![0x22, 0x33, 0x44, 0x00, 0xff, 0x00]);
        let e = format!("{:#}", write_new(&a, &px, (2, 1), PixelOrder::Rgba).unwrap_err());
        assert!(e.contains("exists"), "{e}");
        let b = fresh_name(&dir, "cam 1/final");
        assert_eq!(b, dir.join("cam_1_final-2.png"));
        write_new(&b, &px, (2, 1), PixelOrder::Rgba).unwrap();
        assert_eq!(image::open(&b).unwrap().to_rgb8().as_raw(), &vec![0x44, 0x33, 0x22, 0x00, 0xff, 0x00]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
