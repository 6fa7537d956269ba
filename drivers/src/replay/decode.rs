//! Image decoding into a frame's buffers: colour (PNG or JPEG, RGB8 / RGBA8 / grey) and 16-bit
//! grey PNG depth. Files are read into a reused buffer and decoded in place.

use std::io::{Cursor, Read};
use std::path::Path;

use image::codecs::jpeg::JpegDecoder;
use image::codecs::png::PngDecoder;
use image::{ColorType, ImageDecoder, ImageFormat};

use crate::frame::Intrinsics;

/// Reusable buffers of the decoder (grow to one image's size once, then stay).
#[derive(Debug, Default)]
pub(crate) struct ImageReader {
    file_bytes: Vec<u8>,
    scratch: Vec<u8>,
}

impl ImageReader {
    /// Decodes the colour image at `path` into `rgb` (`width * height * 3` bytes). The error
    /// says what is wrong with the file (the caller names the file).
    pub(crate) fn read_rgb(&mut self, path: &Path, k: &Intrinsics, rgb: &mut [u8]) -> Result<(), String> {
        read_file(path, &mut self.file_bytes)?;
        let bytes = Cursor::new(self.file_bytes.as_slice());
        match image::guess_format(&self.file_bytes) {
            Ok(ImageFormat::Png) => {
                let decoder = PngDecoder::new(bytes).map_err(|e| format!("cannot decode PNG: {e}"))?;
                decode_colour(decoder, "PNG", k, rgb, &mut self.scratch)
            }
            Ok(ImageFormat::Jpeg) => {
                let decoder = JpegDecoder::new(bytes).map_err(|e| format!("cannot decode JPEG: {e}"))?;
                decode_colour(decoder, "JPEG", k, rgb, &mut self.scratch)
            }
            _ => Err("not a PNG or JPEG image".to_owned()),
        }
    }

    /// Decodes the 16-bit grey PNG at `path` into `depth` (`width * height` values).
    pub(crate) fn read_depth(&mut self, path: &Path, k: &Intrinsics, depth: &mut [u16]) -> Result<(), String> {
        read_file(path, &mut self.file_bytes)?;
        if !matches!(image::guess_format(&self.file_bytes), Ok(ImageFormat::Png)) {
            return Err("not a PNG image (depth must be a 16-bit grey PNG)".to_owned());
        }
        let decoder =
            PngDecoder::new(Cursor::new(self.file_bytes.as_slice())).map_err(|e| format!("cannot decode PNG: {e}"))?;
        check_size(decoder.dimensions(), k)?;
        if decoder.color_type() != ColorType::L16 {
            return Err(format!("depth has pixel format {:?}; expected 16-bit grey (L16)", decoder.color_type()));
        }
        // The PNG decoder writes 16-bit samples in native byte order.
        decoder.read_image(bytemuck::cast_slice_mut(depth)).map_err(|e| format!("cannot decode PNG: {e}"))
    }
}

fn read_file(path: &Path, bytes: &mut Vec<u8>) -> Result<(), String> {
    bytes.clear();
    let mut file = std::fs::File::open(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => format!("missing ({e})"),
        _ => format!("cannot open: {e}"),
    })?;
    file.read_to_end(bytes).map_err(|e| format!("cannot read: {e}"))?;
    Ok(())
}

fn check_size((width, height): (u32, u32), k: &Intrinsics) -> Result<(), String> {
    if (width, height) == (k.width, k.height) {
        Ok(())
    } else {
        Err(format!("image is {width}x{height} pixels, the intrinsics say {}x{}", k.width, k.height))
    }
}

fn decode_colour(
    decoder: impl ImageDecoder,
    format: &str,
    k: &Intrinsics,
    rgb: &mut [u8],
    scratch: &mut Vec<u8>,
) -> Result<(), String> {
    check_size(decoder.dimensions(), k)?;
    let failed = |e: image::ImageError| format!("cannot decode {format}: {e}");
    match decoder.color_type() {
        ColorType::Rgb8 => decoder.read_image(rgb).map_err(failed),
        ColorType::Rgba8 => {
            scratch.resize(k.pixel_count() * 4, 0);
            decoder.read_image(scratch).map_err(failed)?;
            for (out, px) in rgb.chunks_exact_mut(3).zip(scratch.chunks_exact(4)) {
                out.copy_from_slice(&px[..3]);
            }
            Ok(())
        }
        ColorType::L8 => {
            scratch.resize(k.pixel_count(), 0);
            decoder.read_image(scratch).map_err(failed)?;
            for (out, grey) in rgb.chunks_exact_mut(3).zip(scratch.iter()) {
                out.fill(*grey);
            }
            Ok(())
        }
        other => Err(format!("colour has pixel format {other:?}; expected 8-bit RGB, RGBA or grey")),
    }
}
