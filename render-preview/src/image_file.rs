//! Image outputs in the format their extension names: PNG (`.png`, or no extension) or
//! JPEG (`.jpg`, `.jpeg`). Any other extension is refused before anything is rendered, so
//! a `.jpg` never holds PNG bytes.

use std::path::Path;

use crate::error::{Error, Result};

/// JPEG quality of preview images (0–100).
pub const JPEG_QUALITY: u8 = 92;

/// An image format the previews are written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum ImageKind {
    /// PNG, lossless.
    Png,
    /// JPEG at [`JPEG_QUALITY`].
    Jpeg,
}

/// The format `path`'s extension names (case-insensitive); no extension means PNG. Err: a
/// one-line reason naming the supported extensions.
pub fn image_kind(path: &Path) -> std::result::Result<ImageKind, String> {
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        None | Some("png") => Ok(ImageKind::Png),
        Some("jpg" | "jpeg") => Ok(ImageKind::Jpeg),
        Some(other) => Err(format!(
            "{}: cannot write .{other} images; name the output .png (PNG) or .jpg/.jpeg (JPEG)",
            path.display()
        )),
    }
}

/// Writes `img` atomically to `path` in the format its extension names ([`image_kind`]).
pub fn write_rgb_image(path: &Path, img: &image::RgbImage) -> Result<()> {
    let fail = |m: String| Error::Output { path: path.to_path_buf(), message: m };
    let kind = image_kind(path).map_err(&fail)?;
    sct_format::atomic::write_atomic(path, |w| {
        let io = |e: image::ImageError| sct_format::Error::Io { path: Some(path.to_path_buf()), source: std::io::Error::other(e) };
        match kind {
            ImageKind::Png => img.write_to(w, image::ImageFormat::Png).map_err(io),
            ImageKind::Jpeg => image::codecs::jpeg::JpegEncoder::new_with_quality(w, JPEG_QUALITY).encode_image(img).map_err(io),
        }
    })
    .map_err(|e| match e {
        // "invalid argument: " adds nothing to "PATH: names a directory; …".
        sct_format::Error::Misuse(m) => fail(m),
        e => fail(e.to_string()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_extension_names_the_format() {
        let dir = tempfile::tempdir().expect("tempdir");
        let img = image::RgbImage::from_pixel(8, 4, image::Rgb([200, 10, 10]));
        for (name, magic) in [("a.png", &b"\x89PNG"[..]), ("b.jpg", &b"\xff\xd8\xff"[..]), ("c.JPEG", &b"\xff\xd8\xff"[..]), ("d", &b"\x89PNG"[..])] {
            let p = dir.path().join(name);
            write_rgb_image(&p, &img).expect("write");
            let bytes = std::fs::read(&p).expect("read");
            assert!(bytes.starts_with(magic), "{name}");
        }
        let e = write_rgb_image(&dir.path().join("e.gif"), &img).unwrap_err().to_string();
        assert!(e.contains(".gif") && e.contains(".jpg"), "{e}");
        assert!(!dir.path().join("e.gif").exists());
    }
}
