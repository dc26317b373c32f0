//! What one rendering returns.

use image::{GrayImage, RgbaImage};
use rayon::prelude::*;
use wide::f64x4;

use super::RenderError;
use super::projection::depth_to_z;
use super::region::Region;
use super::view::RenderView;
use camera::Gray32FImage;

/// Rows per band of the parallel conversion: a few bands per thread at 240 rows and more.
const BAND_ROWS: usize = 32;

isa::dispatch! {
    /// One row of depth bits (`f32`, native byte order) into camera `z` (0 on background) and the
    /// mask (255 where `z > 0`): [`depth_to_z`]'s operations in its order on four lanes of `f64`,
    /// so the values are the same to the last bit. Background (`d = 0`) and non-finite values fail
    /// the `d > 0` lane test or give `z = 0` (`d = ∞`), as [`depth_to_z`]'s `None`.
    fn depth_row(bits: &[u8], near: f64, far: f64, z: &mut [f32], mask: &mut [u8]) {
        let (range, n, nf) = (
            f64x4::splat(far - near),
            f64x4::splat(near),
            f64x4::splat(near * far),
        );
        let zero = f64x4::ZERO;
        let depth = |b: &[u8]| f32::from_bits(u32::from_ne_bytes([b[0], b[1], b[2], b[3]]));
        let mut z4 = z.chunks_exact_mut(4);
        let mut m4 = mask.chunks_exact_mut(4);
        let mut b16 = bits.chunks_exact(16);
        for ((z, m), b) in (&mut z4).zip(&mut m4).zip(&mut b16) {
            let d = f64x4::from([
                depth(&b[0..4]) as f64,
                depth(&b[4..8]) as f64,
                depth(&b[8..12]) as f64,
                depth(&b[12..16]) as f64,
            ]);
            let v = d
                .simd_gt(zero)
                .select(nf / (range * d + n), zero)
                .to_array();
            for k in 0..4 {
                z[k] = v[k] as f32;
                m[k] = if z[k] > 0.0 { 255 } else { 0 };
            }
        }
        let tail = z4.into_remainder().iter_mut().zip(m4.into_remainder());
        for ((z, m), b) in tail.zip(b16.remainder().chunks_exact(4)) {
            *z = depth_to_z(depth(b), near, far).unwrap_or(0.0) as f32;
            *m = if *z > 0.0 { 255 } else { 0 };
        }
    }
}

/// Whether, for clip distances `near` and `far`, the mask's test `z > 0` (in `f32`) is the
/// depth value's being positive and finite: `z` falls as the depth value grows, so it is when
/// the largest finite value still gives a positive `z`. True for any sensible clip distances
/// (0.05 and 50 m give 1.5e-40 there).
fn positive_depth_is_foreground(near: f64, far: f64) -> bool {
    depth_to_z(f32::MAX, near, far).is_some_and(|z| z as f32 > 0.0)
}

isa::dispatch! {
    /// One row of depth bits (`f32`, native byte order) copied into `buffer`, and the mask (255
    /// where `z > 0`, as [`depth_row`]'s): from the bits alone when `bits_decide`
    /// ([`positive_depth_is_foreground`]), which vectorises; else through [`depth_to_z`].
    fn buffer_row(
        bits: &[u8],
        near: f64,
        far: f64,
        bits_decide: bool,
        buffer: &mut [f32],
        mask: &mut [u8],
    ) {
        match bytemuck::try_cast_slice::<u8, f32>(bits) {
            Ok(values) => buffer.copy_from_slice(values),
            Err(_) => {
                for (d, b) in buffer.iter_mut().zip(bits.chunks_exact(4)) {
                    *d = f32::from_ne_bytes([b[0], b[1], b[2], b[3]]);
                }
            }
        }
        if bits_decide {
            // Positive finite values are the bit patterns 1 ..= 0x7f7f_ffff.
            for (m, d) in mask.iter_mut().zip(buffer.iter()) {
                *m = if d.to_bits().wrapping_sub(1) < 0x7f7f_ffff {
                    255
                } else {
                    0
                };
            }
        } else {
            for (m, &d) in mask.iter_mut().zip(buffer.iter()) {
                let z = depth_to_z(d, near, far).unwrap_or(0.0) as f32;
                *m = if z > 0.0 { 255 } else { 0 };
            }
        }
    }
}

/// ITU-R BT.601 luma of an RGBA8 pixel read as a little-endian word, in 16.16 fixed point.
#[inline]
fn luma(p: u32) -> u8 {
    ((19595 * (p & 0xff) + 38470 * ((p >> 8) & 0xff) + 7471 * ((p >> 16) & 0xff) + 32768) >> 16)
        as u8
}

/// One rendered frame, all images row-major with the top row first.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The view this was rendered from.
    pub view: RenderView,
    /// Colour (RGBA8; alpha 0 on background); empty in a frame made by
    /// [`Frame::empty_for_tracker`].
    pub rgba: RgbaImage,
    /// Grayscale, ITU-R BT.601 luma of `rgba`.
    pub gray: GrayImage,
    /// Camera-frame depth `z` in metres (along the optical axis, not the ray); 0 on background.
    /// Empty in a frame made by [`Frame::empty_for_tracker`]: [`Frame::depth_at`] reads it
    /// from the depth buffer's values there.
    pub depth: Gray32FImage,
    /// 255 where the model was rendered, 0 on background.
    pub mask: GrayImage,
    /// The depth buffer's values (reversed depth, [`crate::projection`]), row-major, kept
    /// instead of `depth` by a tracker's frame.
    buffer: Vec<f32>,
    /// Whether the read-back fills `rgba` and `depth` (see [`Frame::empty_for_tracker`]).
    full: bool,
    /// The rectangle the last read-back filled (outside it every image is zero), and the
    /// size of the images it filled.
    filled: Region,
    filled_size: (u32, u32),
}

impl Frame {
    /// Whether the frame holds the images of `view`: filled at exactly that view (the
    /// rendering is deterministic, so rendering it again would give the same images). An
    /// empty frame shows no view.
    pub fn shows(&self, view: &RenderView) -> bool {
        self.filled_size != (0, 0) && self.view == *view
    }

    /// A frame with no pixels, whose buffers [`super::Renderer::render_into`] fills (and
    /// reuses from then on).
    pub fn empty(view: RenderView) -> Self {
        Self {
            view,
            rgba: RgbaImage::new(0, 0),
            gray: GrayImage::new(0, 0),
            depth: Gray32FImage::new(0, 0),
            mask: GrayImage::new(0, 0),
            buffer: Vec::new(),
            full: true,
            filled: Region::default(),
            filled_size: (0, 0),
        }
    }

    /// A frame of given images (a rendering made elsewhere, a test's), all of one size.
    pub fn from_images(
        view: RenderView,
        rgba: RgbaImage,
        gray: GrayImage,
        depth: Gray32FImage,
        mask: GrayImage,
    ) -> Result<Self, RenderError> {
        let sizes = [
            rgba.dimensions(),
            gray.dimensions(),
            depth.dimensions(),
            mask.dimensions(),
        ];
        if sizes.iter().any(|s| *s != sizes[0]) {
            return Err(RenderError::FrameSizes(format!(
                "rgba, gray, depth, mask: {sizes:?}"
            )));
        }
        let (width, height) = sizes[0];
        Ok(Self {
            view,
            rgba,
            gray,
            depth,
            mask,
            buffer: Vec::new(),
            full: true,
            // Images made elsewhere: no pixel is known to be background.
            filled: Region::full(width, height),
            filled_size: (width, height),
        })
    }

    /// As [`Frame::empty`] for a reader of `gray`, `mask` and [`Frame::depth_at`] only (the
    /// tracker): `rgba` stays empty, which spares copying 4 bytes a pixel out of the
    /// read-back, and so does `depth`: the depth buffer's values are kept as they are and
    /// converted to `z` only at the pixels asked for, which spares a division per pixel.
    pub fn empty_for_tracker(view: RenderView) -> Self {
        Self {
            full: false,
            ..Self::empty(view)
        }
    }

    /// Fills the images from the mapped read-back buffers of the rectangle `region` of a
    /// `width × height` rendering (`stride` bytes per row, rows padded to wgpu's copy
    /// alignment), reusing their allocations: a fresh 640×480 frame is 4.6 MB of new pages, and
    /// faulting them in every frame cost more than the conversion itself. Outside `region` the
    /// images are background (zero), as a whole-image read-back gives: only what the last
    /// read-back filled is cleared ([`crate::region`]). Bands of rows are converted in
    /// parallel on rayon's pool.
    pub(crate) fn fill_from_mapped(
        &mut self,
        view: RenderView,
        (width, height): (u32, u32),
        region: Region,
        colour: &[u8],
        depth_bits: &[u8],
        stride: usize,
    ) -> Result<(), RenderError> {
        let size_err = || RenderError::Readback("readback size mismatch".into());
        let (w, h) = (width as usize, height as usize);
        let (rw, rh) = (region.width as usize, region.height as usize);
        if region.x as usize + rw > w
            || region.y as usize + rh > h
            || stride < 4 * rw
            || colour.len() < stride * rh
            || depth_bits.len() < stride * rh
        {
            return Err(size_err());
        }
        let (mut gray, mut z, mut mask, mut rgba) = self.take_background(width, height);
        let (near, far) = (view.near, view.far);
        let full = self.full;
        let bits_decide = positive_depth_is_foreground(near, far);
        let rows = region.rows();
        let (x0, x1) = (region.x as usize, (region.x + region.width) as usize);
        gray[rows.start * w..rows.end * w]
            .par_chunks_mut(w * BAND_ROWS)
            .zip(z[rows.start * w..rows.end * w].par_chunks_mut(w * BAND_ROWS))
            .zip(mask[rows.start * w..rows.end * w].par_chunks_mut(w * BAND_ROWS))
            .enumerate()
            .for_each(|(band, ((gray, z), mask))| {
                let first = band * BAND_ROWS;
                for (k, ((gray, z), mask)) in gray
                    .chunks_exact_mut(w)
                    .zip(z.chunks_exact_mut(w))
                    .zip(mask.chunks_exact_mut(w))
                    .enumerate()
                {
                    let at = (first + k) * stride;
                    let colour = &colour[at..at + 4 * rw];
                    let (gray, z, mask) = (&mut gray[x0..x1], &mut z[x0..x1], &mut mask[x0..x1]);
                    // Each pixel as one little-endian word: over a slice of words (the
                    // mapped rows are aligned) the compiler vectorises the loop.
                    match bytemuck::try_cast_slice::<u8, u32>(colour) {
                        Ok(words) => {
                            for (g, &p) in gray.iter_mut().zip(words) {
                                *g = luma(u32::from_le(p));
                            }
                        }
                        Err(_) => {
                            for (g, p) in gray.iter_mut().zip(colour.chunks_exact(4)) {
                                *g = luma(u32::from_le_bytes([p[0], p[1], p[2], p[3]]));
                            }
                        }
                    }
                    let bits = &depth_bits[at..at + 4 * rw];
                    if full {
                        depth_row(bits, near, far, z, mask);
                    } else {
                        buffer_row(bits, near, far, bits_decide, z, mask);
                    }
                }
            });
        if self.full {
            rgba[4 * rows.start * w..4 * rows.end * w]
                .par_chunks_mut(4 * w)
                .zip(colour.par_chunks(stride))
                .for_each(|(row, src)| row[4 * x0..4 * x1].copy_from_slice(&src[..4 * rw]));
            self.rgba = RgbaImage::from_raw(width, height, rgba).ok_or_else(size_err)?;
        }
        self.view = view;
        self.filled = region;
        self.filled_size = (width, height);
        self.gray = GrayImage::from_raw(width, height, gray).ok_or_else(size_err)?;
        if self.full {
            self.depth = Gray32FImage::from_raw(width, height, z).ok_or_else(size_err)?;
        } else {
            self.buffer = z;
        }
        self.mask = GrayImage::from_raw(width, height, mask).ok_or_else(size_err)?;
        Ok(())
    }

    /// The images' buffers taken out of the frame for `width × height`, all background:
    /// the last read-back's rectangle cleared where they are of that size already (outside it
    /// they are still zero), zeroed whole otherwise. `z` is a full frame's depth or a tracker's
    /// depth buffer; `rgba` is empty in a tracker's frame.
    #[allow(clippy::type_complexity)]
    fn take_background(
        &mut self,
        width: u32,
        height: u32,
    ) -> (Vec<u8>, Vec<f32>, Vec<u8>, Vec<u8>) {
        let (w, n) = (width as usize, width as usize * height as usize);
        let mut gray = std::mem::replace(&mut self.gray, GrayImage::new(0, 0)).into_raw();
        let mut z = if self.full {
            std::mem::replace(&mut self.depth, Gray32FImage::new(0, 0)).into_raw()
        } else {
            std::mem::take(&mut self.buffer)
        };
        let mut mask = std::mem::replace(&mut self.mask, GrayImage::new(0, 0)).into_raw();
        let mut rgba = std::mem::replace(&mut self.rgba, RgbaImage::new(0, 0)).into_raw();
        let rgba_len = if self.full { 4 * n } else { 0 };
        let same_size = self.filled_size == (width, height)
            && gray.len() == n
            && z.len() == n
            && mask.len() == n
            && rgba.len() == rgba_len;
        if same_size {
            let last = self.filled;
            for y in last.rows() {
                let row = y * w;
                let cols = row + last.x as usize..row + (last.x + last.width) as usize;
                gray[cols.clone()].fill(0);
                z[cols.clone()].fill(0.0);
                mask[cols.clone()].fill(0);
                if self.full {
                    rgba[4 * cols.start..4 * cols.end].fill(0);
                }
            }
        } else {
            for v in [&mut gray, &mut mask] {
                v.clear();
                v.resize(n, 0);
            }
            z.clear();
            z.resize(n, 0.0);
            rgba.clear();
            rgba.resize(rgba_len, 0);
        }
        (gray, z, mask, rgba)
    }

    /// The rectangle the last read-back filled: outside it the frame is background.
    pub fn region(&self) -> Region {
        self.filled
    }

    /// Image size `(width, height)`.
    pub fn size(&self) -> (u32, u32) {
        self.gray.dimensions()
    }

    /// Depth `z` (m) at pixel `(u, v)` where the model was rendered: the same value in a full
    /// frame and a tracker's.
    pub fn depth_at(&self, u: u32, v: u32) -> Option<f64> {
        let z = if self.full {
            self.depth.get_pixel_checked(u, v)?.0[0]
        } else {
            let (w, h) = self.size();
            if u >= w || v >= h {
                return None;
            }
            let d = *self.buffer.get(v as usize * w as usize + u as usize)?;
            depth_to_z(d, self.view.near, self.view.far).unwrap_or(0.0) as f32
        };
        (z > 0.0).then_some(z as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use camera::{CameraPose, Pinhole};

    /// The lanes of `depth_row` give `depth_to_z`'s values bit for bit, the tail included,
    /// with each instruction set's copy.
    #[test]
    fn depth_row_equals_depth_to_z() {
        isa::each_copy(|_| depth_row_copy_equals_depth_to_z());
    }

    fn depth_row_copy_equals_depth_to_z() {
        let (near, far) = (0.05, 50.0);
        let mut values = vec![
            0.0f32,
            -0.0,
            -1.0,
            1.0,
            0.5,
            f32::MIN_POSITIVE,
            f32::MIN_POSITIVE / 8.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            1.0e-7,
        ];
        // A deterministic spread of bit patterns over the whole f32 range.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..4000 {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            values.push(f32::from_bits((state >> 32) as u32));
            values.push((state >> 40) as f32 / (1u64 << 24) as f32);
        }
        for width in [1, 3, 4, 5, 8, 11, values.len()] {
            for row in values.chunks(width) {
                let bits: Vec<u8> = row.iter().flat_map(|v| v.to_ne_bytes()).collect();
                let (mut z, mut mask) = (vec![7.0f32; row.len()], vec![7u8; row.len()]);
                depth_row(&bits, near, far, &mut z, &mut mask);
                for ((&d, &z), &m) in row.iter().zip(&z).zip(&mask) {
                    let want = depth_to_z(d, near, far).unwrap_or(0.0) as f32;
                    assert_eq!(z.to_bits(), want.to_bits(), "d = {d:e}");
                    assert_eq!(m, if want > 0.0 { 255 } else { 0 }, "d = {d:e}");
                }
            }
        }
    }

    /// A tracker's frame, filled from the same read-back as a full frame, has the same grey
    /// and mask and the same `z` at every pixel, to the last bit: with the usual clip
    /// distances (the mask from the bits alone) and with ones where the largest depth values
    /// give `z = 0` in `f32` (the mask through `depth_to_z`).
    #[test]
    fn tracker_frames_agree_with_full_frames() {
        let (w, h) = (37u32, 5u32);
        let stride = 4 * w as usize + 12;
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            (state >> 32) as u32
        };
        let special = [
            0.0f32,
            -0.0,
            1.0,
            0.5,
            f32::MAX,
            f32::INFINITY,
            f32::NAN,
            -1.0,
            1e-40,
        ];
        let mut colour = vec![0u8; stride * h as usize];
        let mut depth = vec![0u8; stride * h as usize];
        for (i, (c, d)) in colour
            .chunks_exact_mut(4)
            .zip(depth.chunks_exact_mut(4))
            .enumerate()
        {
            c.copy_from_slice(&next().to_le_bytes());
            let v = match special.get(i % 50) {
                Some(&v) => v,
                None if i % 3 == 0 => f32::from_bits(next()),
                None => (next() >> 8) as f32 / (1u32 << 24) as f32,
            };
            d.copy_from_slice(&v.to_ne_bytes());
        }
        for (near, far, bits_decide) in [(0.05, 50.0, true), (1e-30, 1e30, false)] {
            assert_eq!(positive_depth_is_foreground(near, far), bits_decide);
            let view = RenderView {
                pinhole: Pinhole::new(40.0, 40.0, 18.0, 2.0),
                pose: CameraPose::from_wxyz([1.0, 0.0, 0.0, 0.0], nalgebra::Vector3::zeros())
                    .unwrap(),
                near,
                far,
            };
            let mut full = Frame::empty(view);
            let mut tracker = Frame::empty_for_tracker(view);
            for f in [&mut full, &mut tracker] {
                f.fill_from_mapped(view, (w, h), Region::full(w, h), &colour, &depth, stride)
                    .unwrap();
            }
            assert_eq!(tracker.gray, full.gray);
            assert_eq!(tracker.mask, full.mask);
            assert!(tracker.rgba.is_empty() && tracker.depth.is_empty());
            assert!(full.mask.iter().any(|&m| m > 0) && full.mask.contains(&0));
            for v in 0..h + 1 {
                for u in 0..w + 1 {
                    let (a, b) = (tracker.depth_at(u, v), full.depth_at(u, v));
                    assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "({u}, {v})");
                }
            }
        }
    }

    /// The read-back of `r` out of a whole image: the whole image's pixels inside `r`
    /// with background (zero) outside, and `r`'s rows alone at a padded stride.
    #[allow(clippy::type_complexity)]
    fn cut(
        colour: &[u8],
        depth: &[u8],
        stride: usize,
        r: Region,
    ) -> (Vec<u8>, Vec<u8>, Vec<u8>, Vec<u8>, usize) {
        let (mut whole_c, mut whole_d) = (vec![0u8; colour.len()], vec![0u8; depth.len()]);
        let rstride = 4 * r.width as usize + 8;
        let mut part_c = vec![0u8; rstride * r.height as usize];
        let mut part_d = vec![0u8; rstride * r.height as usize];
        for (k, y) in r.rows().enumerate() {
            let cols = y * stride + 4 * r.x as usize..y * stride + 4 * (r.x + r.width) as usize;
            whole_c[cols.clone()].copy_from_slice(&colour[cols.clone()]);
            whole_d[cols.clone()].copy_from_slice(&depth[cols.clone()]);
            let n = 4 * r.width as usize;
            part_c[k * rstride..k * rstride + n].copy_from_slice(&colour[cols.clone()]);
            part_d[k * rstride..k * rstride + n].copy_from_slice(&depth[cols]);
        }
        (whole_c, whole_d, part_c, part_d, rstride)
    }

    /// A read-back of a rectangle gives the frame a whole-image read-back gives where the
    /// rendering is background outside it, in full frames and trackers' alike, whatever
    /// rectangle the frame's last read-back filled.
    #[test]
    fn a_region_reads_as_the_whole_image_with_background_outside() {
        let (w, h) = (45u32, 37u32);
        let stride = 4 * w as usize + 20;
        let mut state = 0x853c_49e6_748f_ea9bu64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            (state >> 32) as u32
        };
        // A whole image of random pixels, and the read-back of `r` out of it with the
        // whole image's background outside `r` (colour and depth zero).
        let mut colour = vec![0u8; stride * h as usize];
        let mut depth = vec![0u8; stride * h as usize];
        for (c, d) in colour.chunks_exact_mut(4).zip(depth.chunks_exact_mut(4)) {
            c.copy_from_slice(&next().to_le_bytes());
            let v = (next() >> 8) as f32 / (1u32 << 24) as f32;
            d.copy_from_slice(&v.to_ne_bytes());
        }
        let view = RenderView {
            pinhole: Pinhole::new(40.0, 40.0, 22.0, 18.0),
            pose: CameraPose::from_wxyz([1.0, 0.0, 0.0, 0.0], nalgebra::Vector3::zeros()).unwrap(),
            near: 0.05,
            far: 50.0,
        };
        let rect = |x, y, width, height| Region {
            x,
            y,
            width,
            height,
        };
        let regions = [
            rect(3, 4, 20, 30),
            rect(10, 0, 35, 9),
            rect(0, 0, 1, 1),
            Region::full(w, h),
            rect(44, 36, 1, 1),
        ];
        for make in [Frame::empty, Frame::empty_for_tracker] {
            let mut focused = make(view);
            for r in regions {
                let (whole_c, whole_d, part_c, part_d, rstride) = cut(&colour, &depth, stride, r);
                let mut whole = make(view);
                whole
                    .fill_from_mapped(view, (w, h), Region::full(w, h), &whole_c, &whole_d, stride)
                    .unwrap();
                focused
                    .fill_from_mapped(view, (w, h), r, &part_c, &part_d, rstride)
                    .unwrap();
                assert_eq!(focused.region(), r);
                assert_eq!(focused.gray, whole.gray, "{r:?}");
                assert_eq!(focused.mask, whole.mask, "{r:?}");
                assert_eq!(focused.rgba, whole.rgba, "{r:?}");
                for (a, b) in focused.depth.iter().zip(whole.depth.iter()) {
                    assert_eq!(a.to_bits(), b.to_bits());
                }
                for v in 0..h {
                    for u in 0..w {
                        assert_eq!(focused.depth_at(u, v), whole.depth_at(u, v));
                    }
                }
            }
        }
        // A rectangle outside the image, or rows shorter than it, is refused.
        let mut f = Frame::empty(view);
        let outside = rect(40, 0, 10, 2);
        assert!(
            f.fill_from_mapped(view, (w, h), outside, &colour, &depth, stride)
                .is_err()
        );
    }

    /// A frame of images that disagree in size is refused with the sizes named.
    #[test]
    fn from_images_refuses_images_of_different_sizes() {
        let view = RenderView {
            pinhole: Pinhole::new(100.0, 100.0, 15.5, 11.5),
            pose: CameraPose::from_wxyz([1.0, 0.0, 0.0, 0.0], nalgebra::Vector3::zeros()).unwrap(),
            near: 0.1,
            far: 10.0,
        };
        let images = |w: u32| {
            (
                RgbaImage::new(32, 24),
                GrayImage::new(32, 24),
                Gray32FImage::new(w, 24),
                GrayImage::new(32, 24),
            )
        };
        let (rgba, gray, depth, mask) = images(32);
        let frame = Frame::from_images(view, rgba, gray, depth, mask).unwrap();
        assert_eq!(frame.size(), (32, 24));
        let (rgba, gray, depth, mask) = images(31);
        let err = Frame::from_images(view, rgba, gray, depth, mask).unwrap_err();
        assert!(err.to_string().contains("(31, 24)"), "{err}");
    }
}
