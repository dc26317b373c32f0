//! The focused read-back (issue 39): the rectangle of the image the model can cover at a view,
//! from its bounding box projected. Only that rectangle is rasterised (a scissor), copied out
//! of the GPU and converted; the rest of the frame is background, zero as a whole-image
//! read-back leaves it. The model of a tracker covers a sixth of the image or less, so the
//! read-back shrinks with the object instead of with the image, bit for bit the same.

use nalgebra::Vector3;

use super::RenderView;

/// A rectangle of pixels, `[x, x + width) × [y, y + height)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Region {
    /// First column.
    pub x: u32,
    /// First row.
    pub y: u32,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

impl Region {
    /// The whole `width × height` image.
    pub fn full(width: u32, height: u32) -> Self {
        Self {
            x: 0,
            y: 0,
            width,
            height,
        }
    }

    /// Pixels in the rectangle.
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Its columns as a range.
    pub fn columns(&self) -> std::ops::Range<usize> {
        self.x as usize..(self.x + self.width) as usize
    }

    /// Its rows as a range.
    pub fn rows(&self) -> std::ops::Range<usize> {
        self.y as usize..(self.y + self.height) as usize
    }
}

/// Pixels of margin around the projected box. The GPU projects in `f32`, the box here in
/// `f64`; a pixel is covered where its centre lies inside a triangle, so a covered pixel's
/// coordinate is within the projected box up to rounding, far below a pixel.
const MARGIN_PX: f64 = 2.0;

/// The rectangle of a `width × height` image outside which nothing of the model inside the box
/// `bounds` (its least and greatest corner, model frame) can be rasterised at `view`.
///
/// Where every corner of the box lies beyond the near plane, the box's image is the convex hull
/// of its corners' images (a perspective projection keeps lines straight in front of the
/// camera), and clipping at the far plane only removes from it: the rectangle is their
/// bounding box with [`MARGIN_PX`] around it, clipped to the image. Otherwise (a corner at or
/// behind the near plane, or a value that is not finite) it is the whole image. A model wholly
/// outside the image gets one pixel, which is background.
pub fn covered_region(
    bounds: &([f32; 3], [f32; 3]),
    view: &RenderView,
    width: u32,
    height: u32,
) -> Region {
    let full = Region::full(width, height);
    let (lo, hi) = bounds;
    let k = &view.pinhole;
    let (mut u_min, mut u_max) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut v_min, mut v_max) = (f64::INFINITY, f64::NEG_INFINITY);
    for corner in 0..8 {
        let pick = |axis: usize| {
            f64::from(if corner & (1 << axis) == 0 {
                lo[axis]
            } else {
                hi[axis]
            })
        };
        let p = view
            .pose
            .world_to_camera(&Vector3::new(pick(0), pick(1), pick(2)));
        if !(p.z > view.near && p.z.is_finite()) {
            return full;
        }
        let u = (k.fx * p.x + k.skew * p.y) / p.z + k.cx;
        let v = k.fy * p.y / p.z + k.cy;
        if !(u.is_finite() && v.is_finite()) {
            return full;
        }
        (u_min, u_max) = (u_min.min(u), u_max.max(u));
        (v_min, v_max) = (v_min.min(v), v_max.max(v));
    }
    // First and one-past-last pixel of each axis, clipped to the image.
    let span = |lo: f64, hi: f64, size: u32| {
        let first = (lo - MARGIN_PX).floor().clamp(0.0, f64::from(size)) as u32;
        let end = ((hi + MARGIN_PX).ceil() + 1.0).clamp(0.0, f64::from(size)) as u32;
        (first, end)
    };
    let (x0, x1) = span(u_min, u_max, width);
    let (y0, y1) = span(v_min, v_max, height);
    if x1 <= x0 || y1 <= y0 {
        return Region {
            x: 0,
            y: 0,
            width: width.min(1),
            height: height.min(1),
        };
    }
    Region {
        x: x0,
        y: y0,
        width: x1 - x0,
        height: y1 - y0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use camera::{CameraPose, Pinhole};

    fn view(c_w: [f64; 3]) -> RenderView {
        RenderView {
            pinhole: Pinhole::new(500.0, 500.0, 319.5, 239.5),
            pose: CameraPose::from_wxyz([1.0, 0.0, 0.0, 0.0], Vector3::from(c_w)).unwrap(),
            near: 0.05,
            far: 50.0,
        }
    }

    const CUBE: ([f32; 3], [f32; 3]) = ([-0.05, -0.05, -0.05], [0.05, 0.05, 0.05]);

    /// A cube ahead of the camera: its corners' images, with the margin.
    #[test]
    fn a_box_ahead_covers_its_projection() {
        // Camera at z = -1 looking along +z: the near face at 0.95 m spans ±26.3 px.
        let r = covered_region(&CUBE, &view([0.0, 0.0, -1.0]), 640, 480);
        let half = 500.0 * 0.05 / 0.95;
        assert_eq!(r.x, (319.5 - half - MARGIN_PX).floor() as u32);
        assert_eq!(r.x + r.width, (319.5 + half + MARGIN_PX).ceil() as u32 + 1);
        assert!(r.pixels() < 70 * 70, "{r:?}");
    }

    /// A corner behind the near plane: the whole image. Wholly outside the image: one pixel.
    #[test]
    fn near_and_outside_boxes() {
        assert_eq!(
            covered_region(&CUBE, &view([0.0, 0.0, -0.07]), 640, 480),
            Region::full(640, 480)
        );
        let r = covered_region(&CUBE, &view([5.0, 0.0, -1.0]), 640, 480);
        assert_eq!(
            r,
            Region {
                x: 0,
                y: 0,
                width: 1,
                height: 1
            }
        );
        // Partly outside: clipped to the image.
        let r = covered_region(&CUBE, &view([0.6, 0.0, -1.0]), 640, 480);
        assert_eq!(r.x, 0);
        assert!(r.width > 30 && r.width < 70, "{r:?}");
    }
}
