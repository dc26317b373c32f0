//! Camera frames from image files (PNG, JPEG: a EuRoC `cam0/data` folder, `--images`,
//! `locate --image`), read within limits checked before the pixels are allocated (issue 40):
//! a file over [`MAX_FRAME_FILE_BYTES`] is refused from its size, an image whose header gives a
//! side over [`crate::MAX_IMAGE_SIDE`] from its header, and the decoder allocates at most
//! [`MAX_FRAME_DECODED_BYTES`].

use std::io::{Cursor, ErrorKind};
use std::path::Path;

use image::{DynamicImage, ImageError, ImageReader, Limits};

use crate::MAX_IMAGE_SIDE;

/// Largest frame file read [bytes]: a 16384² PNG of noise is under 1 GiB.
pub const MAX_FRAME_FILE_BYTES: u64 = 1 << 30;

/// Most the decoder of one frame allocates [bytes]: a 16384² RGBA image.
pub const MAX_FRAME_DECODED_BYTES: u64 = 4 * (MAX_IMAGE_SIDE as u64) * (MAX_IMAGE_SIDE as u64);

/// The decoder limits of a frame: [`MAX_IMAGE_SIDE`] a side, [`MAX_FRAME_DECODED_BYTES`].
pub fn frame_limits() -> Limits {
    let mut limits = Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    limits.max_alloc = Some(MAX_FRAME_DECODED_BYTES);
    limits
}

/// An error of invalid data, with what is wrong in words.
fn invalid(what: String) -> ImageError {
    ImageError::IoError(std::io::Error::new(ErrorKind::InvalidData, what))
}

/// Decodes a PNG or JPEG frame within [`frame_limits`]: the header's size is checked first, and
/// an image over the limits is an error that names them.
pub fn decode_frame(bytes: &[u8]) -> Result<DynamicImage, ImageError> {
    let reader = || ImageReader::new(Cursor::new(bytes)).with_guessed_format();
    let (w, h) = reader().map_err(ImageError::IoError)?.into_dimensions()?;
    if w == 0 || h == 0 || w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        return Err(invalid(format!(
            "{w}x{h} px: not a usable frame (1 to {MAX_IMAGE_SIDE} px a side)"
        )));
    }
    let mut reader = reader().map_err(ImageError::IoError)?;
    reader.limits(frame_limits());
    reader.decode().map_err(|e| match e {
        ImageError::Limits(l) => invalid(format!(
            "{w}x{h} px: {l} (at most {MAX_FRAME_DECODED_BYTES} bytes decoded)"
        )),
        e => e,
    })
}

/// Reads and decodes the frame file `path` ([`decode_frame`]); a file over
/// [`MAX_FRAME_FILE_BYTES`] is refused from its size, before it is read.
pub fn read_frame(path: &Path) -> Result<DynamicImage, ImageError> {
    let len = std::fs::metadata(path).map_err(ImageError::IoError)?.len();
    if len > MAX_FRAME_FILE_BYTES {
        return Err(invalid(format!(
            "{len} bytes: too large for a frame (at most {MAX_FRAME_FILE_BYTES})"
        )));
    }
    decode_frame(&std::fs::read(path).map_err(ImageError::IoError)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::GrayImage;

    fn png(w: u32, h: u32) -> Vec<u8> {
        let mut out = Vec::new();
        GrayImage::from_fn(w, h, |x, y| image::Luma([(x * 7 + y * 3) as u8]))
            .write_to(&mut Cursor::new(&mut out), image::ImageFormat::Png)
            .unwrap();
        out
    }

    /// CRC-32 (IEEE, reflected), as PNG chunks carry it.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = !0u32;
        for &b in bytes {
            c ^= u32::from(b);
            for _ in 0..8 {
                c = if c & 1 == 1 {
                    (c >> 1) ^ 0xEDB8_8320
                } else {
                    c >> 1
                };
            }
        }
        !c
    }

    /// A PNG whose header says `w × h`, its IHDR's CRC made to match.
    fn png_claiming(w: u32, h: u32) -> Vec<u8> {
        let mut bytes = png(4, 4);
        bytes[16..20].copy_from_slice(&w.to_be_bytes());
        bytes[20..24].copy_from_slice(&h.to_be_bytes());
        let crc = crc32(&bytes[12..29]);
        bytes[29..33].copy_from_slice(&crc.to_be_bytes());
        bytes
    }

    #[test]
    fn a_frame_decodes_as_written() {
        let img = decode_frame(&png(33, 17)).unwrap().into_luma8();
        assert_eq!(img.dimensions(), (33, 17));
        assert_eq!(img.get_pixel(5, 2)[0], 41);
    }

    #[test]
    fn a_header_over_the_side_limit_is_refused_by_name() {
        for (w, h) in [(MAX_IMAGE_SIDE + 1, 4), (4, u32::MAX), (100_000, 100_000)] {
            let e = decode_frame(&png_claiming(w, h)).unwrap_err().to_string();
            assert!(e.contains(&format!("{w}x{h} px")), "{e}");
            assert!(e.contains("16384"), "{e}");
        }
    }

    #[test]
    fn empty_truncated_and_foreign_bytes_are_errors() {
        let good = png(8, 8);
        for bytes in [
            &[][..],
            &good[..20],
            &good[..good.len() - 5],
            b"P5 8 8 255\n",
        ] {
            assert!(decode_frame(bytes).is_err());
        }
        let dir = tempfile::tempdir().unwrap();
        let e = read_frame(&dir.path().join("absent.png")).unwrap_err();
        assert!(matches!(e, ImageError::IoError(_)));
    }
}
