//! numpy frames read as the tracker's grey images: `uint8`, grey `H×W` or colour `H×W×3`
//! (OpenCV's BGR by default). The array is read in place, without an intermediate copy; the
//! tracker keeps a grey image of its own, since it analyses the frame on its own thread
//! after `push_frame` has returned.

use ::image::GrayImage;
use numpy::{
    PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use crate::error::value_error;

/// The order of a colour frame's three channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channels {
    /// Blue, green, red: OpenCV's `VideoCapture` and `imread`.
    Bgr,
    /// Red, green, blue: PIL, imageio, matplotlib.
    Rgb,
}

impl Channels {
    /// `"bgr"` or `"rgb"`.
    pub fn parse(s: &str) -> PyResult<Self> {
        match s.to_ascii_lowercase().as_str() {
            "bgr" => Ok(Channels::Bgr),
            "rgb" => Ok(Channels::Rgb),
            _ => Err(value_error(format!(
                "channels must be \"bgr\" (OpenCV) or \"rgb\", got {s:?}"
            ))),
        }
    }
}

/// ITU-R BT.601 luma in 8-bit fixed point (weights ×256, summing to 256), as ffmpeg's
/// `format=gray` and OpenCV's `COLOR_BGR2GRAY` compute it: the grey the command line's
/// video frames have.
fn luma(r: u8, g: u8, b: u8) -> u8 {
    let y = 77 * u32::from(r) + 150 * u32::from(g) + 29 * u32::from(b) + 128;
    (y >> 8) as u8
}

/// The grey image of `array` (`what` names it in errors): `uint8`, `H×W` or `H×W×3`.
pub fn gray_of(array: &Bound<'_, PyAny>, channels: Channels, what: &str) -> PyResult<GrayImage> {
    let untyped = array.cast::<PyUntypedArray>().map_err(|_| {
        value_error(format!(
            "{what}: expected a numpy array (uint8, H×W grey or H×W×3 colour), got {}",
            array
                .get_type()
                .name()
                .map_or_else(|_| "?".into(), |n| n.to_string())
        ))
    })?;
    let dtype = untyped.dtype();
    if !dtype.is_equiv_to(&numpy::dtype::<u8>(array.py())) {
        return Err(value_error(format!(
            "{what}: the array's dtype is {dtype}, expected uint8 (8-bit pixels; convert with .astype(numpy.uint8) after scaling)"
        )));
    }
    let shape = untyped.shape().to_vec();
    let (h, w, c) = match shape[..] {
        [h, w] => (h, w, 1),
        [h, w, 3] => (h, w, 3),
        [h, w, 1] => (h, w, 1),
        _ => {
            return Err(value_error(format!(
                "{what}: the array's shape is {shape:?}, expected (height, width) grey or (height, width, 3) colour"
            )));
        }
    };
    let too_big = |n: usize| n == 0 || n > camera::MAX_IMAGE_SIDE as usize;
    if too_big(h) || too_big(w) {
        return Err(value_error(format!(
            "{what}: {w}x{h} pixels: each side must be 1 to {} pixels",
            camera::MAX_IMAGE_SIDE
        )));
    }
    let typed = array
        .cast::<PyArrayDyn<u8>>()
        .map_err(|e| value_error(format!("{what}: {e}")))?;
    let read = typed.readonly();
    let mut out = Vec::with_capacity(h * w);
    match (read.as_slice(), c) {
        // C-contiguous: the rows as they lie.
        (Ok(pixels), 1) => out.extend_from_slice(pixels),
        (Ok(pixels), _) => out.extend(pixels.chunks_exact(3).map(|p| pixel(p, channels))),
        // Strided (a crop, a transposed view): element by element.
        (Err(_), _) => {
            let view = read.as_array();
            let at = |y: usize, x: usize, k: usize| match shape.len() {
                2 => view[[y, x].as_slice()],
                _ => view[[y, x, k].as_slice()],
            };
            for y in 0..h {
                for x in 0..w {
                    out.push(match c {
                        1 => at(y, x, 0),
                        _ => pixel(&[at(y, x, 0), at(y, x, 1), at(y, x, 2)], channels),
                    });
                }
            }
        }
    }
    GrayImage::from_raw(w as u32, h as u32, out)
        .ok_or_else(|| value_error(format!("{what}: {w}x{h} pixels do not fill the image")))
}

/// The grey of one colour pixel in `channels` order.
fn pixel(p: &[u8], channels: Channels) -> u8 {
    match channels {
        Channels::Bgr => luma(p[2], p[1], p[0]),
        Channels::Rgb => luma(p[0], p[1], p[2]),
    }
}
