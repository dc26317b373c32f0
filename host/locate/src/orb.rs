//! Oriented FAST and rotated BRIEF keypoints (Rublee et al., "ORB: an efficient alternative
//! to SIFT or SURF", ICCV 2011), for finding the model without a pose
//! (docs/notes/issue15-cold-start.md §1).
//!
//! - A scale pyramid (factor [`OrbConfig::scale`]); on each level FAST-9 corners
//!   ([`features::fast`]) ranked by the Harris response (eq. C1), the best kept in
//!   proportion to the level's area.
//! - Orientation by the intensity centroid of a disc of radius [`PATCH_RADIUS`] (eq. C2).
//! - A 256-bit binary test descriptor on the Gaussian-smoothed level (eq. C3): pairs drawn once
//!   from an isotropic Gaussian (BRIEF's G II), steered by the orientation in 32 steps.
//!
//! The test pattern is drawn from a fixed seed, so every build describes the same image the same
//! way, and a cached database stays valid.

use image::GrayImage;
use image::imageops::{self, FilterType};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};

use features::fast;

/// A 256-bit binary descriptor.
pub type Descriptor = [u64; 4];

/// Radius of the disc the orientation and the tests use [px of the level].
pub const PATCH_RADIUS: i32 = 15;

/// Steering steps over a full turn.
const ANGLE_STEPS: usize = 32;

/// Seed of the test pattern (any fixed value: it is part of the descriptor's definition).
const PATTERN_SEED: u64 = 0x00b5_e55e_d0fb_21ef;

/// Detector and descriptor settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrbConfig {
    /// Pyramid levels.
    pub levels: usize,
    /// Scale between levels.
    pub scale: f32,
    /// FAST threshold.
    pub fast_threshold: u8,
    /// Keypoints over all levels, at most.
    pub max_keypoints: usize,
    /// σ of the smoothing the binary tests run on [px of the level].
    pub smoothing: f32,
}

impl Default for OrbConfig {
    fn default() -> Self {
        Self {
            levels: 6,
            scale: 1.3,
            fast_threshold: 20,
            max_keypoints: 1000,
            smoothing: 2.0,
        }
    }
}

/// A keypoint with its descriptor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    /// Position in the full-resolution image [px, pixel centres at integers].
    pub x: f32,
    /// Position in the full-resolution image [px].
    pub y: f32,
    /// Pyramid level it was found on.
    pub level: u8,
    /// Orientation [rad].
    pub angle: f32,
    /// Harris response (ranking only).
    pub response: f32,
    /// The binary descriptor.
    pub descriptor: Descriptor,
}

/// Number of differing bits.
#[inline(always)]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    a.iter().zip(b).map(|(x, y)| (x ^ y).count_ones()).sum()
}

/// The detector with its steered test patterns.
#[derive(Debug, Clone)]
pub struct Orb {
    config: OrbConfig,
    /// Per steering step, 256 pairs of offsets `(x1, y1, x2, y2)`.
    steered: Vec<[[i8; 4]; 256]>,
}

/// Border a keypoint keeps on its level: the disc plus FAST's circle.
const BORDER: i32 = PATCH_RADIUS + 4;

impl Orb {
    /// The detector for `config`.
    pub fn new(config: OrbConfig) -> Self {
        // BRIEF G II: both points of a test i.i.d. N(0, S²/25) for a patch of side S = 31,
        // redrawn until inside the disc, so that every steered copy stays inside it too.
        let mut rng = StdRng::seed_from_u64(PATTERN_SEED);
        let sigma = (2 * PATCH_RADIUS + 1) as f64 / 5.0;
        let normal = Normal::new(0.0, sigma).unwrap_or_else(|_| unreachable!("σ > 0"));
        let r2 = (PATCH_RADIUS * PATCH_RADIUS) as f64;
        let mut draw = || loop {
            let (x, y) = (normal.sample(&mut rng), normal.sample(&mut rng));
            if x * x + y * y <= r2 {
                return (x, y);
            }
        };
        let base: Vec<[(f64, f64); 2]> = (0..256).map(|_| [draw(), draw()]).collect();
        let steered = (0..ANGLE_STEPS)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / ANGLE_STEPS as f64;
                let (s, c) = a.sin_cos();
                let rot = |(x, y): (f64, f64)| {
                    let rx = (c * x - s * y).round().clamp(-15.0, 15.0) as i8;
                    let ry = (s * x + c * y).round().clamp(-15.0, 15.0) as i8;
                    (rx, ry)
                };
                let mut out = [[0i8; 4]; 256];
                for (o, [p, q]) in out.iter_mut().zip(&base) {
                    let (a, b) = rot(*p);
                    let (cc, d) = rot(*q);
                    *o = [a, b, cc, d];
                }
                out
            })
            .collect();
        Self { config, steered }
    }

    /// The settings.
    pub fn config(&self) -> &OrbConfig {
        &self.config
    }

    /// Keypoints of `image`; with `mask`, only those whose disc centre and a ring of radius
    /// `PATCH_RADIUS / 2` around it lie on set mask pixels (a rendering's silhouette edge
    /// against its empty background describes nothing the live image has).
    pub fn detect(&self, image: &GrayImage, mask: Option<&GrayImage>) -> Vec<Keypoint> {
        let c = &self.config;
        let (w0, h0) = image.dimensions();
        // Budget per level in proportion to its area: n_k ∝ s^(−2k).
        let ratios: Vec<f64> = (0..c.levels)
            .map(|k| f64::from(c.scale).powi(-2 * k as i32))
            .collect();
        let total: f64 = ratios.iter().sum();
        let mut out = Vec::new();
        for (k, ratio) in ratios.iter().enumerate() {
            let factor = f64::from(c.scale).powi(k as i32);
            let (w, h) = (
                (f64::from(w0) / factor).round() as u32,
                (f64::from(h0) / factor).round() as u32,
            );
            if (w as i32) < 2 * BORDER + 1 || (h as i32) < 2 * BORDER + 1 {
                break;
            }
            let level = if k == 0 {
                image.clone()
            } else {
                imageops::resize(image, w, h, FilterType::Triangle)
            };
            let budget = ((c.max_keypoints as f64) * ratio / total).round() as usize;
            let smooth = imageops::blur(&level, c.smoothing);
            let sx = f64::from(w0) / f64::from(w);
            let sy = f64::from(h0) / f64::from(h);
            let to_full = |x: i32, y: i32| {
                (
                    ((f64::from(x) + 0.5) * sx - 0.5) as f32,
                    ((f64::from(y) + 0.5) * sy - 0.5) as f32,
                )
            };
            let on_mask = |x: i32, y: i32| {
                let Some(m) = mask else { return true };
                let half = PATCH_RADIUS / 2;
                [(0, 0), (half, 0), (-half, 0), (0, half), (0, -half)]
                    .iter()
                    .all(|(dx, dy)| {
                        let (fx, fy) = to_full(x + dx, y + dy);
                        let (u, v) = (fx.round() as i64, fy.round() as i64);
                        u >= 0
                            && v >= 0
                            && u < i64::from(m.width())
                            && v < i64::from(m.height())
                            && m.get_pixel(u as u32, v as u32).0[0] > 0
                    })
            };
            let mut corners: Vec<(f32, i32, i32)> = fast::detect(&level, c.fast_threshold, true)
                .into_iter()
                .map(|p| (p.x as i32, p.y as i32))
                .filter(|&(x, y)| {
                    x >= BORDER && y >= BORDER && x < w as i32 - BORDER && y < h as i32 - BORDER
                })
                .filter(|&(x, y)| on_mask(x, y))
                .map(|(x, y)| (harris(&level, x, y), x, y))
                .collect();
            corners.sort_by(|a, b| b.0.total_cmp(&a.0).then((a.2, a.1).cmp(&(b.2, b.1))));
            corners.truncate(budget);
            for (response, x, y) in corners {
                let angle = centroid_angle(&level, x, y);
                let (fx, fy) = to_full(x, y);
                out.push(Keypoint {
                    x: fx,
                    y: fy,
                    level: k as u8,
                    angle,
                    response,
                    descriptor: self.describe(&smooth, x, y, angle),
                });
            }
        }
        out
    }

    /// Eq. C3: bit i is `I_σ(p + R(θ) a_i) < I_σ(p + R(θ) b_i)`, θ rounded to a steering step.
    fn describe(&self, smooth: &GrayImage, x: i32, y: i32, angle: f32) -> Descriptor {
        let step = (f64::from(angle) / std::f64::consts::TAU * ANGLE_STEPS as f64).round() as i64;
        let pattern = &self.steered[step.rem_euclid(ANGLE_STEPS as i64) as usize];
        let at = |dx: i8, dy: i8| {
            smooth
                .get_pixel((x + i32::from(dx)) as u32, (y + i32::from(dy)) as u32)
                .0[0]
        };
        let mut d = [0u64; 4];
        for (i, [ax, ay, bx, by]) in pattern.iter().enumerate() {
            if at(*ax, *ay) < at(*bx, *by) {
                d[i / 64] |= 1 << (i % 64);
            }
        }
        d
    }
}

/// Eq. C1: Harris response `det M − 0.04 (tr M)²` of the 7×7 window around `(x, y)`, with
/// central-difference gradients (the caller keeps `(x, y)` `BORDER` inside the image).
fn harris(img: &GrayImage, x: i32, y: i32) -> f32 {
    let px = |u: i32, v: i32| f32::from(img.get_pixel(u as u32, v as u32).0[0]);
    let (mut a, mut b, mut c) = (0.0f32, 0.0f32, 0.0f32);
    for v in y - 3..=y + 3 {
        for u in x - 3..=x + 3 {
            let gx = px(u + 1, v) - px(u - 1, v);
            let gy = px(u, v + 1) - px(u, v - 1);
            a += gx * gx;
            b += gy * gy;
            c += gx * gy;
        }
    }
    a * b - c * c - 0.04 * (a + b) * (a + b)
}

/// Eq. C2: `θ = atan2(m01, m10)`, the moments of the disc of radius `PATCH_RADIUS` around
/// `(x, y)`.
fn centroid_angle(img: &GrayImage, x: i32, y: i32) -> f32 {
    let (mut m10, mut m01) = (0i64, 0i64);
    let r = PATCH_RADIUS;
    for dy in -r..=r {
        let half = ((r * r - dy * dy) as f64).sqrt() as i32;
        for dx in -half..=half {
            let i = i64::from(img.get_pixel((x + dx) as u32, (y + dy) as u32).0[0]);
            m10 += i64::from(dx) * i;
            m01 += i64::from(dy) * i;
        }
    }
    (m01 as f32).atan2(m10 as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;

    /// A textured test image: blobs of several sizes on a gradient.
    fn texture(w: u32, h: u32) -> GrayImage {
        let mut rng = StdRng::seed_from_u64(7);
        let blobs: Vec<(f64, f64, f64, f64)> = (0..120)
            .map(|_| {
                (
                    rng.random_range(0.0..f64::from(w)),
                    rng.random_range(0.0..f64::from(h)),
                    rng.random_range(2.0..9.0),
                    rng.random_range(-120.0..120.0),
                )
            })
            .collect();
        GrayImage::from_fn(w, h, |x, y| {
            let mut v = 100.0 + 0.1 * f64::from(x);
            for (bx, by, r, a) in &blobs {
                let d2 = (f64::from(x) - bx).powi(2) + (f64::from(y) - by).powi(2);
                v += a * (-d2 / (2.0 * r * r)).exp();
            }
            image::Luma([v.clamp(0.0, 255.0) as u8])
        })
    }

    /// Matches of `a` in `b` (nearest descriptor) that land within `tol` px of `map(a)`.
    fn repeatability(
        a: &[Keypoint],
        b: &[Keypoint],
        map: impl Fn(f32, f32) -> (f32, f32),
        tol: f32,
    ) -> f64 {
        let good = a
            .iter()
            .filter(|ka| {
                let best = b
                    .iter()
                    .min_by_key(|kb| hamming(&ka.descriptor, &kb.descriptor))
                    .copied();
                best.is_some_and(|kb| {
                    let (x, y) = map(ka.x, ka.y);
                    (kb.x - x).hypot(kb.y - y) <= tol
                })
            })
            .count();
        good as f64 / a.len().max(1) as f64
    }

    #[test]
    fn descriptors_match_across_a_rotation_and_a_scale_change() {
        let img = texture(320, 240);
        let orb = Orb::new(OrbConfig::default());
        let a = orb.detect(&img, None);
        assert!(a.len() > 100, "{} keypoints", a.len());
        // The same image turned by 90° (x' = h − 1 − y, y' = x).
        let (w, h) = img.dimensions();
        let turned = GrayImage::from_fn(h, w, |x, y| *img.get_pixel(y, h - 1 - x));
        let b = orb.detect(&turned, None);
        let r = repeatability(&a, &b, |x, y| ((h - 1) as f32 - y, x), 2.0);
        assert!(r > 0.5, "rotation: {r}");
        // Scaled by 1.5.
        let big = imageops::resize(&img, 480, 360, FilterType::Triangle);
        let c = orb.detect(&big, None);
        let r = repeatability(
            &a,
            &c,
            |x, y| ((x + 0.5) * 1.5 - 0.5, (y + 0.5) * 1.5 - 0.5),
            3.0,
        );
        assert!(r > 0.3, "scale: {r}");
    }

    #[test]
    fn the_mask_keeps_keypoints_off_the_background_and_flat_images_have_none() {
        let img = texture(320, 240);
        let orb = Orb::new(OrbConfig::default());
        let mask = GrayImage::from_fn(320, 240, |x, _| {
            image::Luma([if x < 160 { 255 } else { 0 }])
        });
        let k = orb.detect(&img, Some(&mask));
        assert!(!k.is_empty());
        assert!(
            k.iter().all(|p| p.x < 160.0 - 6.0),
            "a keypoint near the mask's edge"
        );
        assert!(orb.detect(&GrayImage::new(320, 240), None).is_empty());
        assert!(orb.detect(&GrayImage::new(20, 20), None).is_empty());
    }

    #[test]
    fn the_pattern_is_fixed_and_hamming_counts_bits() {
        let a = Orb::new(OrbConfig::default());
        let b = Orb::new(OrbConfig::default());
        assert_eq!(a.steered, b.steered);
        assert_eq!(hamming(&[0, 0, 0, 0], &[1, 3, 0, u64::MAX]), 67);
    }
}
