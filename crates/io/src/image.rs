//! Style paintings in, preview pictures out.

use std::path::Path;

use image::imageops::FilterType;
use nst3d_core::Image;

use crate::atomic::write_atomic;
use crate::{Error, ErrorKind};

/// Largest side we accept for a style image after scaling: the VGG pass on it
/// grows with the area, and 2048² already takes minutes on a farm CPU.
pub const MAX_STYLE_SIDE: usize = 2048;

/// Reads a style painting as a 3 x H x W RGB image in `[0, 1]`, resized by
/// `scale` (the paper's style-image scale factor: smaller images give larger
/// patterns). Resizing uses a triangle filter with antialiasing so shrinking a
/// painting does not alias its brush strokes.
pub fn load_style(path: &Path, scale: f32) -> Result<Image, Error> {
    let read_err = |reason: String| Error::new(path, ErrorKind::ImageRead { reason });
    let size_err = |reason: String| Error::new(path, ErrorKind::ImageSize { reason });
    if !(scale.is_finite() && scale > 0.0) {
        return Err(size_err(format!("style scale must be a positive number, got {scale}")));
    }
    let reader = image::ImageReader::open(path)
        .map_err(|e| read_err(e.to_string()))?
        .with_guessed_format()
        .map_err(|e| read_err(e.to_string()))?;
    let img = reader.decode().map_err(|e| read_err(e.to_string()))?.to_rgb8();
    let (w0, h0) = img.dimensions();
    let w = ((w0 as f32 * scale).round() as usize).max(1);
    let h = ((h0 as f32 * scale).round() as usize).max(1);
    if w < 16 || h < 16 || w > MAX_STYLE_SIDE || h > MAX_STYLE_SIDE {
        return Err(size_err(format!(
            "scaled style image is {w}x{h}; each side must be 16..={MAX_STYLE_SIDE} pixels (adjust --style-scale)"
        )));
    }
    let img = if (w as u32, h as u32) != (w0, h0) {
        image::imageops::resize(&img, w as u32, h as u32, FilterType::Triangle)
    } else {
        img
    };
    let mut out = Image::zeros(3, h, w);
    for (x, y, p) in img.enumerate_pixels() {
        for c in 0..3 {
            out.data[(c * h + y as usize) * w + x as usize] = p[c] as f32 / 255.0;
        }
    }
    Ok(out)
}

/// The painting's luminance (Rec. 601 weights, as PIL's `convert("L")`)
/// repeated in three channels: the transmittance renderer draws grey smoke,
/// so a grey painting's Gram statistics are the ones it can actually reach.
pub fn luminance_rgb(img: &Image) -> Image {
    img.luminance3()
}

/// Converts a 1- or 3-channel image with values in `[0, 1]` to 8-bit RGB
/// (values outside are clipped).
pub fn to_rgb8(img: &Image) -> image::RgbImage {
    let (w, h) = (img.width, img.height);
    let mut out = image::RgbImage::new(w as u32, h as u32);
    for y in 0..h {
        for x in 0..w {
            let mut px = [0u8; 3];
            for (c, v) in px.iter_mut().enumerate() {
                let ch = if img.channels == 3 { c } else { 0 };
                let f = img.data[(ch * h + y) * w + x];
                *v = (f.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            }
            out.put_pixel(x as u32, y as u32, image::Rgb(px));
        }
    }
    out
}

/// Places images left to right on a black canvas (for before/after sheets).
pub fn side_by_side(images: &[&Image]) -> Image {
    let h = images.iter().map(|i| i.height).max().unwrap_or(0);
    let w: usize = images.iter().map(|i| i.width).sum();
    let mut out = Image::zeros(3, h, w);
    let mut x0 = 0;
    for img in images {
        for c in 0..3 {
            let src = if img.channels == 3 { c } else { 0 };
            for y in 0..img.height {
                let s = &img.data[(src * img.height + y) * img.width..][..img.width];
                out.data[(c * h + y) * w + x0..][..img.width].copy_from_slice(s);
            }
        }
        x0 += img.width;
    }
    out
}

/// Height in pixels of nst3d's preview sheets (volumes and grooms alike),
/// tall enough to judge strokes, small enough to open anywhere.
pub const PREVIEW_HEIGHT: usize = 384;

/// Resizes to `height` rows keeping the aspect ratio (triangle filter), for
/// previews of small grids that would otherwise be a few dozen pixels tall.
pub fn resize_to_height(img: &Image, height: usize) -> Image {
    let width = ((img.width * height) as f32 / img.height.max(1) as f32).round().max(1.0) as usize;
    let mut out = Image::zeros(img.channels, height, width);
    for c in 0..img.channels {
        let plane = image::ImageBuffer::<image::Luma<f32>, Vec<f32>>::from_raw(
            img.width as u32,
            img.height as u32,
            img.channel(c).to_vec(),
        )
        .expect("plane size matches");
        let r = image::imageops::resize(&plane, width as u32, height as u32, FilterType::Triangle);
        out.data[c * height * width..(c + 1) * height * width].copy_from_slice(r.as_raw());
    }
    out
}

/// Writes a PNG atomically (temporary name, then rename).
pub fn write_png(path: &Path, img: &Image) -> Result<(), Error> {
    let rgb = to_rgb8(img);
    write_atomic(path, |w| {
        let mut buf = std::io::Cursor::new(Vec::new());
        rgb.write_to(&mut buf, image::ImageFormat::Png).map_err(std::io::Error::other)?;
        w.write_all(buf.get_ref())
    })
    .map_err(|e| Error::new(path, ErrorKind::ImageWrite { reason: e.to_string() }))
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;

    fn style(name: &str) -> PathBuf {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/styles").join(name);
        assert!(p.exists(), "shared test data missing: {} (the repo expects ../shared beside it)", p.display());
        p
    }

    #[test]
    fn reads_the_shared_painting_scaled() {
        let img = load_style(&style("starry_night.jpg"), 0.25).unwrap();
        assert_eq!(img.channels, 3);
        assert!(img.width > 100 && img.height > 50);
        assert!(img.data.iter().all(|v| (0.0..=1.0).contains(v)));
    }

    #[test]
    fn bad_style_files_give_errors() {
        let dir = tempfile::tempdir().unwrap();
        let junk = dir.path().join("junk.jpg");
        std::fs::write(&junk, b"not a jpeg at all").unwrap();
        assert!(load_style(&junk, 1.0).unwrap_err().to_string().contains("junk.jpg"));
        assert!(load_style(&dir.path().join("missing.png"), 1.0).is_err());
        assert!(load_style(&style("starry_night.jpg"), 0.001).is_err());
    }

    #[test]
    fn png_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        let img = Image::from_vec(1, 2, 3, vec![0.0, 0.5, 1.0, 1.0, 0.5, 0.0]);
        write_png(&p, &side_by_side(&[&img, &img])).unwrap();
        let back = image::open(&p).unwrap().to_rgb8();
        assert_eq!(back.dimensions(), (6, 2));
        assert_eq!(back.get_pixel(1, 0)[0], 128);
    }
}
