//! A precomputed map that rectifies whole images (bilinear), like OpenCV's
//! `initUndistortRectifyMap` + `remap`.
//!
//! The map is the `f32` source point of every target pixel. For speed it is also kept as what
//! the bilinear interpolation needs of it, precomputed once (OpenCV's fixed-point map idea, but
//! with the `f32` weights, so the values stay those of the per-pixel formula to the last bit):
//! per target pixel the offset of its top-left source pixel and the two fractions, and per
//! run of target pixels whether they are outside (0), inside with all four neighbours (the fast
//! path: no clamping, no branch), or on the last source row or column (the per-pixel formula
//! with its clamping). docs/VISION.md §1.

use image::{GrayImage, ImageBuffer, Luma};
use nalgebra::Vector2;
use wide::{f32x8, i16x8, i32x8, u8x16};

use super::{Camera, CameraError, MAX_IMAGE_SIDE, Pinhole};

/// A single-channel `f32` image.
pub type Gray32FImage = ImageBuffer<Luma<f32>, Vec<f32>>;

/// For every pixel of the rectified (ideal pinhole) image, where to sample the distorted
/// source image.
///
/// Coordinates follow the pixel-centre convention of [`crate`]. The map stores `f32`
/// coordinates (round-off ≤ 1e-4 px for images up to 2000 px, far below what bilinear
/// interpolation resolves); the point functions of [`Camera`] are the `f64` reference.
#[derive(Debug, Clone)]
pub struct UndistortMap {
    width: u32,
    height: u32,
    src_width: u32,
    src_height: u32,
    /// Source pixel of each target pixel, row-major; NaN where the source is outside the image.
    map: Vec<[f32; 2]>,
    /// The bilinear taps of each target pixel (meaningful where its run is [`RunKind::Inside`]).
    taps: Taps,
    /// Consecutive target pixels (row-major, across rows) of one kind, in order, covering all.
    runs: Vec<Run>,
}

/// The bilinear interpolation of each target pixel whose four source neighbours are inside
/// the image, as arrays over the target pixels (so the fractions load as whole vectors): the
/// top-left neighbour's row-major index, and the fractions as the per-pixel formula computes
/// them from the map (`x − ⌊x⌋`, `y − ⌊y⌋`).
#[derive(Debug, Clone, Default)]
struct Taps {
    offset: Vec<u32>,
    ax: Vec<f32>,
    ay: Vec<f32>,
}

/// How a run of target pixels is rectified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum RunKind {
    /// Source outside the image: 0.
    Outside,
    /// All four neighbours inside: the fast path.
    Inside,
    /// On the source's last row or column (the interpolation's second neighbour clamped): the
    /// per-pixel formula.
    Edge,
}

/// Target pixels `start .. start + len` (row-major) of one kind.
#[derive(Debug, Clone, Copy)]
struct Run {
    start: usize,
    len: usize,
    kind: RunKind,
}

/// Target pixels interpolated per chunk: the gathers fill arrays, the arithmetic and the
/// rounding then run on whole vectors.
const CHUNK: usize = 8;

/// Target pixels gathered before they are interpolated (a multiple of [`CHUNK`]).
const BLOCK: usize = 128;

impl UndistortMap {
    /// Map to an ideal pinhole image with the source's size and intrinsics.
    pub fn new(camera: &Camera) -> Result<Self, CameraError> {
        Self::with_target(camera, &camera.pinhole, camera.width, camera.height)
    }

    /// Map to an ideal pinhole image with intrinsics `target` and size `width × height`.
    pub fn with_target(
        camera: &Camera,
        target: &Pinhole,
        width: u32,
        height: u32,
    ) -> Result<Self, CameraError> {
        if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
            return Err(CameraError::BadSize { width, height });
        }
        if camera.width == 0 || camera.height == 0 {
            return Err(CameraError::BadSize {
                width: camera.width,
                height: camera.height,
            });
        }
        target.validate()?;
        let (sw, sh) = (camera.width as f64, camera.height as f64);
        let mut map = Vec::with_capacity(width as usize * height as usize);
        for v in 0..height {
            for u in 0..width {
                let n = target.to_normalised(Vector2::new(u as f64, v as f64));
                let s = camera.normalised_to_pixel(n);
                let inside = s.x >= 0.0 && s.y >= 0.0 && s.x <= sw - 1.0 && s.y <= sh - 1.0;
                // Clamped because the f32 rounding may step just outside the image.
                map.push(if inside {
                    [
                        (s.x as f32).clamp(0.0, (sw - 1.0) as f32),
                        (s.y as f32).clamp(0.0, (sh - 1.0) as f32),
                    ]
                } else {
                    [f32::NAN; 2]
                });
            }
        }
        let (taps, runs) = taps_and_runs(&map, camera.width, camera.height);
        Ok(Self {
            width,
            height,
            src_width: camera.width,
            src_height: camera.height,
            map,
            taps,
            runs,
        })
    }

    /// Rectified image size `(width, height)`.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Where rectified pixel `(u, v)` samples the source; `None` outside either image.
    pub fn source_of(&self, u: u32, v: u32) -> Option<[f32; 2]> {
        if u >= self.width || v >= self.height {
            return None;
        }
        let s = self.map[(v * self.width + u) as usize];
        (!s[0].is_nan()).then_some(s)
    }

    /// Rectifies an 8-bit image; pixels whose source is outside the image are 0.
    pub fn remap_gray(&self, src: &GrayImage) -> Result<GrayImage, CameraError> {
        self.check_source(src.width(), src.height())?;
        let raw = src.as_raw().as_slice();
        let sw = src.width() as usize;
        let mut out = vec![0u8; self.map.len()];
        for run in &self.runs {
            let range = run.start..run.start + run.len;
            match run.kind {
                RunKind::Outside => {}
                RunKind::Inside => inside_u8(raw, sw, &self.taps, range, &mut out),
                RunKind::Edge => {
                    for (o, &s) in out[range.clone()].iter_mut().zip(&self.map[range]) {
                        *o = round_u8(self.bilinear_clamped(s, |i| raw[i] as f32));
                    }
                }
            }
        }
        GrayImage::from_raw(self.width, self.height, out).ok_or(CameraError::BadSize {
            width: self.width,
            height: self.height,
        })
    }

    /// Rectifies an `f32` image; pixels whose source is outside the image are 0.
    pub fn remap_f32(&self, src: &Gray32FImage) -> Result<Gray32FImage, CameraError> {
        self.check_source(src.width(), src.height())?;
        let raw = src.as_raw().as_slice();
        let sw = src.width() as usize;
        let mut out = vec![0f32; self.map.len()];
        for run in &self.runs {
            let range = run.start..run.start + run.len;
            match run.kind {
                RunKind::Outside => {}
                RunKind::Inside => inside_f32(raw, sw, &self.taps, range, &mut out),
                RunKind::Edge => {
                    for (o, &s) in out[range.clone()].iter_mut().zip(&self.map[range]) {
                        *o = self.bilinear_clamped(s, |i| raw[i]);
                    }
                }
            }
        }
        Gray32FImage::from_raw(self.width, self.height, out).ok_or(CameraError::BadSize {
            width: self.width,
            height: self.height,
        })
    }

    fn check_source(&self, width: u32, height: u32) -> Result<(), CameraError> {
        if (width, height) != (self.src_width, self.src_height) {
            return Err(CameraError::BadSize { width, height });
        }
        Ok(())
    }

    /// The per-pixel bilinear formula at a valid source point `[x, y]` (`0 ≤ x ≤ w−1`,
    /// `0 ≤ y ≤ h−1`), the second neighbour clamped to the image. [`inside_u8`] and
    /// [`inside_f32`] compute the same expression where no clamping is needed.
    #[inline]
    fn bilinear_clamped(&self, [x, y]: [f32; 2], get: impl Fn(usize) -> f32) -> f32 {
        let sw = self.src_width as usize;
        let (max_x, max_y) = (self.src_width - 1, self.src_height - 1);
        let (x0, y0) = (x.floor() as u32, y.floor() as u32);
        let (ax, ay) = (x - x0 as f32, y - y0 as f32);
        let (x1, y1) = ((x0 + 1).min(max_x), (y0 + 1).min(max_y));
        let at = |xx: u32, yy: u32| get(yy as usize * sw + xx as usize);
        let top = at(x0, y0) * (1.0 - ax) + at(x1, y0) * ax;
        let bottom = at(x0, y1) * (1.0 - ax) + at(x1, y1) * ax;
        top * (1.0 - ay) + bottom * ay
    }
}

/// The rounding of [`UndistortMap::remap_gray`]: nearest, clamped to `0..=255`.
#[inline]
fn round_u8(v: f32) -> u8 {
    (v + 0.5).clamp(0.0, 255.0) as u8
}

/// The taps of every target pixel and the runs of one kind (see [`RunKind`]).
fn taps_and_runs(map: &[[f32; 2]], src_width: u32, src_height: u32) -> (Taps, Vec<Run>) {
    let sw = src_width as usize;
    let mut taps = Taps {
        offset: Vec::with_capacity(map.len()),
        ax: Vec::with_capacity(map.len()),
        ay: Vec::with_capacity(map.len()),
    };
    let mut runs: Vec<Run> = Vec::new();
    for (i, &[x, y]) in map.iter().enumerate() {
        let (kind, offset, ax, ay) = if x.is_nan() {
            (RunKind::Outside, 0, 0.0, 0.0)
        } else {
            // As the per-pixel formula: the map keeps 0 ≤ x ≤ w−1, 0 ≤ y ≤ h−1.
            let (x0, y0) = (x.floor() as u32, y.floor() as u32);
            let offset = (y0 as usize * sw + x0 as usize) as u32;
            let kind = if x0 + 1 < src_width && y0 + 1 < src_height {
                RunKind::Inside
            } else {
                RunKind::Edge
            };
            (kind, offset, x - x0 as f32, y - y0 as f32)
        };
        taps.offset.push(offset);
        taps.ax.push(ax);
        taps.ay.push(ay);
        match runs.last_mut() {
            Some(r) if r.kind == kind => r.len += 1,
            _ => runs.push(Run {
                start: i,
                len: 1,
                kind,
            }),
        }
    }
    (taps, runs)
}

/// Up to [`CHUNK`] values from `s` as a full vector (the rest 0); a full chunk is one load.
#[inline(always)]
fn chunk_f32(s: &[f32]) -> f32x8 {
    match <[f32; CHUNK]>::try_from(s) {
        Ok(a) => f32x8::new(a),
        Err(_) => {
            let mut a = [0f32; CHUNK];
            for (a, &v) in a.iter_mut().zip(s) {
                *a = v;
            }
            f32x8::new(a)
        }
    }
}

/// The per-pixel formula of [`UndistortMap::bilinear_clamped`] on whole vectors: the same
/// operations in the same order (`a`, `b` the top neighbours, `c`, `d` the bottom ones).
#[inline(always)]
fn interpolate([a, b, c, d]: [f32x8; 4], ax: f32x8, ay: f32x8) -> f32x8 {
    let one = f32x8::ONE;
    let top = a * (one - ax) + b * ax;
    let bottom = c * (one - ax) + d * ax;
    top * (one - ay) + bottom * ay
}

isa::dispatch! {
    /// The [`RunKind::Inside`] pixels `range` of an 8-bit image into `out`, [`BLOCK`] pixels at a
    /// time: first the gathers, per pixel two 2-byte loads packed into one `u32` (`a | b << 8 | c
    /// << 16 | d << 24`), then unpacking, conversion, interpolation and rounding on vectors of
    /// eight. Two passes over a block rather than one per chunk: a vector load right after the
    /// eight scalar stores it reads stalls (the stores cannot be forwarded to it).
    fn inside_u8(
        src: &[u8],
        sw: usize,
        taps: &Taps,
        range: std::ops::Range<usize>,
        out: &mut [u8],
    ) {
        let (half, byte) = (f32x8::splat(0.5), i32x8::splat(0xff));
        let blocks = taps.offset[range.clone()]
            .chunks(BLOCK)
            .zip(taps.ax[range.clone()].chunks(BLOCK))
            .zip(taps.ay[range.clone()].chunks(BLOCK))
            .zip(out[range].chunks_mut(BLOCK));
        let mut packed = [0i32; BLOCK];
        for (((offsets, ax), ay), out) in blocks {
            for (p, &i) in packed.iter_mut().zip(offsets) {
                let i = i as usize;
                // One bounds check for the four neighbours (an inside run has x0 + 1 < w,
                // y0 + 1 < h).
                let q = &src[i..i + sw + 2];
                let pair = |k: usize| i32::from(u16::from_le_bytes([q[k], q[k + 1]]));
                let (top, bottom) = (pair(0), pair(sw));
                *p = top | bottom << 16;
            }
            let chunks = packed
                .chunks_exact(CHUNK)
                .zip(ax.chunks(CHUNK))
                .zip(ay.chunks(CHUNK))
                .zip(out.chunks_mut(CHUNK));
            for (((p, ax), ay), o) in chunks {
                let v = i32x8::new(p.try_into().expect("a chunk"));
                let abcd = [
                    v & byte,
                    (v >> 8) & byte,
                    (v >> 16) & byte,
                    (v >> 24) & byte,
                ]
                .map(f32x8::from_i32x8);
                let v = interpolate(abcd, chunk_f32(ax), chunk_f32(ay));
                // `round_u8`: + 0.5, truncate, and the clamp to 0..=255 from the saturating packs
                // (i32 → i16 → u8): the same byte for every |v| < 2³¹ and for NaN (0), and v, a
                // convex combination of bytes, is within 0 ..= 255 (+ rounding).
                let q = i16x8::from_i32x8_saturate((v + half).fast_trunc_int());
                let q = u8x16::narrow_i16x8(q, q).to_array();
                match <&mut [u8; CHUNK]>::try_from(&mut *o) {
                    Ok(o) => o.copy_from_slice(&q[..CHUNK]),
                    Err(_) => {
                        for (o, &q) in o.iter_mut().zip(&q) {
                            *o = q;
                        }
                    }
                }
            }
        }
    }
}

isa::dispatch! {
    /// The [`RunKind::Inside`] pixels `range` of an `f32` image into `out`.
    fn inside_f32(
        src: &[f32],
        sw: usize,
        taps: &Taps,
        range: std::ops::Range<usize>,
        out: &mut [f32],
    ) {
        let chunks = taps.offset[range.clone()]
            .chunks(CHUNK)
            .zip(taps.ax[range.clone()].chunks(CHUNK))
            .zip(taps.ay[range.clone()].chunks(CHUNK))
            .zip(out[range].chunks_mut(CHUNK));
        for (((offsets, ax), ay), o) in chunks {
            let mut g = [[0f32; CHUNK]; 4];
            for (j, &i) in offsets.iter().enumerate().take(CHUNK) {
                let i = i as usize;
                let q = &src[i..i + sw + 2];
                g[0][j] = q[0];
                g[1][j] = q[1];
                g[2][j] = q[sw];
                g[3][j] = q[sw + 1];
            }
            let v = interpolate(g.map(f32x8::new), chunk_f32(ax), chunk_f32(ay)).to_array();
            match <&mut [f32; CHUNK]>::try_from(&mut *o) {
                Ok(o) => *o = v,
                Err(_) => {
                    for (o, &v) in o.iter_mut().zip(&v) {
                        *o = v;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    //! The run-based remap against the per-pixel formula it replaced (kept here verbatim as
    //! `reference`): equal to the last bit, for 8-bit and `f32` images, on maps with outside
    //! pixels, pixels on the last source row and column, odd and tiny sizes, and the real
    //! EuRoC calibration and frame.
    use super::*;
    use crate::Distortion;
    use proptest::prelude::*;

    /// The remap before the runs: per pixel, the clamped bilinear formula (unchanged).
    fn reference(map: &UndistortMap, src_width: u32, get: impl Fn(usize) -> f32) -> Vec<f32> {
        let sw = src_width as usize;
        let (max_x, max_y) = (map.src_width - 1, map.src_height - 1);
        map.map
            .iter()
            .map(|&[x, y]| {
                if x.is_nan() {
                    return 0.0;
                }
                let (x0, y0) = (x.floor() as u32, y.floor() as u32);
                let (ax, ay) = (x - x0 as f32, y - y0 as f32);
                let (x1, y1) = ((x0 + 1).min(max_x), (y0 + 1).min(max_y));
                let at = |xx: u32, yy: u32| get(yy as usize * sw + xx as usize);
                let top = at(x0, y0) * (1.0 - ax) + at(x1, y0) * ax;
                let bottom = at(x0, y1) * (1.0 - ax) + at(x1, y1) * ax;
                top * (1.0 - ay) + bottom * ay
            })
            .collect()
    }

    fn reference_gray(map: &UndistortMap, src: &GrayImage) -> Vec<u8> {
        let raw = src.as_raw();
        reference(map, src.width(), |i| raw[i] as f32)
            .into_iter()
            .map(|x| (x + 0.5).clamp(0.0, 255.0) as u8)
            .collect()
    }

    fn lcg(seed: &mut u64) -> u64 {
        *seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        *seed >> 33
    }

    /// Asserts both remaps equal the reference on random images (`f32` bit for bit), with each
    /// instruction set's copy of the kernels.
    fn check(map: &UndistortMap, cam: &Camera, seed: &mut u64) {
        isa::each_copy(|_| check_copy(map, cam, seed));
    }

    fn check_copy(map: &UndistortMap, cam: &Camera, seed: &mut u64) {
        let (w, h) = (cam.width, cam.height);
        let gray = GrayImage::from_fn(w, h, |_, _| Luma([(lcg(seed) % 256) as u8]));
        let fast = map.remap_gray(&gray).unwrap();
        assert_eq!(fast.as_raw(), &reference_gray(map, &gray), "{w}x{h} u8");
        let f = Gray32FImage::from_fn(w, h, |_, _| {
            Luma([(lcg(seed) % 100_000) as f32 / 97.0 - 300.0])
        });
        let fast = map.remap_f32(&f).unwrap();
        let raw = f.as_raw();
        let want = reference(map, w, |i| raw[i]);
        for (i, (a, b)) in fast.as_raw().iter().zip(&want).enumerate() {
            assert_eq!(a.to_bits(), b.to_bits(), "{w}x{h} f32 at {i}: {a} vs {b}");
        }
    }

    fn cameras(w: u32, h: u32) -> Vec<Camera> {
        let (fw, fh) = (w as f64, h as f64);
        let k = Pinhole::new(
            0.6 * fw + 1.0,
            0.6 * fw + 1.0,
            (fw - 1.0) / 2.0,
            (fh - 1.0) / 2.0,
        );
        [
            Distortion::None,
            Distortion::RadTan {
                k1: -0.28,
                k2: 0.074,
                p1: 0.0002,
                p2: 1.8e-5,
                k3: 0.0,
            },
            Distortion::RadTan {
                k1: 0.2,
                k2: 0.0,
                p1: 0.001,
                p2: -0.002,
                k3: 0.0,
            },
            Distortion::Equidistant {
                k1: 0.0034823,
                k2: 0.0007150,
                k3: -0.0020532,
                k4: 0.0002029,
            },
        ]
        .into_iter()
        .map(|d| Camera::new(w, h, k, d).unwrap())
        .collect()
    }

    #[test]
    fn remap_equals_the_per_pixel_formula_on_small_images() {
        let mut seed = 5;
        let mut edge_pixels = 0;
        for (w, h) in [
            (1, 1),
            (1, 5),
            (5, 1),
            (2, 2),
            (2, 3),
            (3, 2),
            (7, 5),
            (8, 8),
            (9, 13),
            (16, 9),
            (17, 17),
            (31, 24),
            (64, 40),
        ] {
            for cam in cameras(w, h) {
                // The camera's own ideal image, and a zoomed-out and a shifted target (more
                // pixels outside, sources on the last row and column).
                let k = cam.pinhole;
                let targets = [
                    (k, w, h),
                    (Pinhole::new(0.5 * k.fx, 0.5 * k.fy, k.cx, k.cy), w, h),
                    (k, w + 3, h + 1),
                ];
                for (t, tw, th) in targets {
                    let map = UndistortMap::with_target(&cam, &t, tw, th).unwrap();
                    edge_pixels += map
                        .runs
                        .iter()
                        .filter(|r| r.kind == RunKind::Edge)
                        .map(|r| r.len)
                        .sum::<usize>();
                    check(&map, &cam, &mut seed);
                }
            }
        }
        assert!(edge_pixels > 0, "no pixel on the last source row or column");
    }

    #[test]
    fn remap_equals_the_per_pixel_formula_on_the_euroc_calibration() {
        let dir = std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../shared/data/euroc-v101-micro/mav0/cam0"
        ));
        let Ok(calib) = crate::read_euroc_sensor_yaml(&dir.join("sensor.yaml")) else {
            eprintln!("SKIPPED: no EuRoC calibration under {}", dir.display());
            return;
        };
        let cam = calib.camera;
        let map = UndistortMap::new(&cam).unwrap();
        let mut seed = 9;
        check(&map, &cam, &mut seed);
        let frame = dir.join("data/1403715273262142976.png");
        if let Ok(img) = image::open(&frame) {
            let img = img.to_luma8();
            assert_eq!(
                map.remap_gray(&img).unwrap().as_raw(),
                &reference_gray(&map, &img)
            );
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn remap_equals_the_per_pixel_formula_on_random_cameras(
            w in 1u32..40, h in 1u32..40, k1 in -0.4f64..0.4, p1 in -0.01f64..0.01,
            zoom in 0.3f64..1.5, dx in -5.0f64..5.0, seed in 0u64..1000,
        ) {
            let (fw, fh) = (w as f64, h as f64);
            let k = Pinhole::new(0.7 * fw + 1.0, 0.7 * fw + 1.0, (fw - 1.0) / 2.0, (fh - 1.0) / 2.0);
            let d = Distortion::RadTan { k1, k2: 0.0, p1, p2: 0.0, k3: 0.0 };
            let cam = Camera::new(w, h, k, d).unwrap();
            let t = Pinhole::new(zoom * k.fx, zoom * k.fy, k.cx + dx, k.cy);
            let map = UndistortMap::with_target(&cam, &t, w, h).unwrap();
            let mut seed = seed;
            check(&map, &cam, &mut seed);
        }
    }
}
