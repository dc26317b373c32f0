//! Points on the outer contour of a rendering (docs/VISION.md §9.1): the mask's border pixels,
//! spread over a grid, each with the outward normal of the mask and the model point the depth
//! buffer puts there.

use image::GrayImage;
use nalgebra::{Matrix3, Vector2, Vector3};

use render::Frame;
use render::backproject::backproject;

/// Where contour points are sampled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleConfig {
    /// Most points per frame.
    pub max_points: usize,
    /// Side of the grid cells that hold one point each [px]: the points' spacing.
    pub spacing_px: f64,
    /// Half side of the window the normal is estimated over [px].
    pub normal_radius: i64,
    /// Pixel uncertainty of a contour point's position along the rendering [px] (the mask is
    /// sampled at pixel centres): it enters the model point's covariance.
    pub sigma_px: f64,
}

impl Default for SampleConfig {
    fn default() -> Self {
        Self {
            max_points: 160,
            spacing_px: 8.0,
            normal_radius: 3,
            sigma_px: 0.5,
        }
    }
}

/// One point of the rendered contour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContourSample {
    /// The contour's position in the rendering [px]: the edge between a border pixel of the
    /// mask and the background, half a pixel out from the pixel's centre along the normal.
    pub pixel: Vector2<f64>,
    /// Unit normal, pointing out of the silhouette, in pixel coordinates.
    pub normal: Vector2<f64>,
    /// The model point there, in the world [m].
    pub m_w: Vector3<f64>,
    /// Its covariance [m²].
    pub cov_w: Matrix3<f64>,
}

/// Whether `(x, y)` is a pixel of `mask` that is set.
fn inside(mask: &GrayImage, x: i64, y: i64) -> bool {
    let (w, h) = mask.dimensions();
    x >= 0 && y >= 0 && x < w as i64 && y < h as i64 && mask.get_pixel(x as u32, y as u32).0[0] > 0
}

/// Whether the pixel nearest `p` is a pixel of `mask` that is set.
pub(crate) fn covers(mask: &GrayImage, p: Vector2<f64>) -> bool {
    p.x.is_finite() && p.y.is_finite() && inside(mask, p.x.round() as i64, p.y.round() as i64)
}

/// The outward normal of the mask at `(x, y)`: away from the centroid of the set pixels of the
/// `(2r+1)²` window around it (a smoothed gradient of the mask); `None` where the window is
/// symmetric (a one-pixel line, a corner's tip).
fn outward_normal(mask: &GrayImage, x: i64, y: i64, r: i64) -> Option<Vector2<f64>> {
    let mut sum = Vector2::zeros();
    for dy in -r..=r {
        for dx in -r..=r {
            if inside(mask, x + dx, y + dy) {
                sum -= Vector2::new(dx as f64, dy as f64);
            }
        }
    }
    let norm = sum.norm();
    (norm > 0.5).then(|| sum / norm)
}

/// Border pixels of `mask`: set, with a 4-neighbour that is not, at least `margin` pixels from
/// the image's edge (where the silhouette is the image's border, not the object's, and the
/// normal's window would leave the image).
fn border_pixels(mask: &GrayImage, margin: i64) -> Vec<(i64, i64)> {
    let (w, h) = (mask.width() as i64, mask.height() as i64);
    let mut out = Vec::new();
    for y in margin..h - margin {
        for x in margin..w - margin {
            if inside(mask, x, y)
                && !(inside(mask, x - 1, y)
                    && inside(mask, x + 1, y)
                    && inside(mask, x, y - 1)
                    && inside(mask, x, y + 1))
            {
                out.push((x, y));
            }
        }
    }
    out
}

/// Contour points of `frame`: per grid cell of `spacing_px`, the border pixel nearest the
/// cell's centre, then at most `max_points` of them, evenly over the list. Border pixels
/// without a normal or a depth are skipped.
pub fn sample(frame: &Frame, cfg: &SampleConfig) -> Vec<ContourSample> {
    let mask = &frame.mask;
    let spacing = cfg.spacing_px.max(1.0);
    let border = border_pixels(mask, cfg.normal_radius.max(0) + 1);
    let cells_x = (mask.width() as f64 / spacing).ceil() as usize + 1;
    // Per cell: the best pixel and its squared distance to the cell's centre.
    let mut best: std::collections::HashMap<usize, ((i64, i64), f64)> = Default::default();
    for &(x, y) in &border {
        let (cx, cy) = ((x as f64 / spacing) as usize, (y as f64 / spacing) as usize);
        let centre = Vector2::new((cx as f64 + 0.5) * spacing, (cy as f64 + 0.5) * spacing);
        let d2 = (Vector2::new(x as f64, y as f64) - centre).norm_squared();
        let cell = cy * cells_x + cx;
        let e = best.entry(cell).or_insert(((x, y), d2));
        if d2 < e.1 {
            *e = ((x, y), d2);
        }
    }
    let mut chosen: Vec<(usize, (i64, i64))> = best.into_iter().map(|(c, (p, _))| (c, p)).collect();
    // Cell order: deterministic whatever the hash map's.
    chosen.sort_unstable_by_key(|(c, _)| *c);
    let stride = chosen.len().div_ceil(cfg.max_points.max(1)).max(1);
    chosen
        .iter()
        .step_by(stride)
        .filter_map(|&(_, (x, y))| {
            let normal = outward_normal(mask, x, y, cfg.normal_radius)?;
            let z = frame.depth_at(x as u32, y as u32)?;
            let pixel = Vector2::new(x as f64, y as f64) + normal * 0.5;
            let b = backproject(&frame.view, pixel.x, pixel.y, z, cfg.sigma_px);
            Some(ContourSample {
                pixel,
                normal,
                m_w: b.p_w,
                cov_w: b.cov_w,
            })
        })
        .collect()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use camera::Gray32FImage;
    use camera::{CameraPose, Pinhole};
    use image::{Luma, RgbaImage};
    use nalgebra::UnitQuaternion;
    use render::RenderView;

    /// A rendering of a fronto-parallel disc of radius `radius` px centred at `centre`, 1 m in
    /// front of a camera at the origin looking along +z.
    pub(crate) fn disc_frame(size: (u32, u32), centre: (f64, f64), radius: f64) -> Frame {
        let view = RenderView {
            pinhole: Pinhole::new(500.0, 500.0, size.0 as f64 / 2.0, size.1 as f64 / 2.0),
            pose: CameraPose {
                q_cw: UnitQuaternion::identity(),
                c_w: Vector3::zeros(),
            },
            near: 0.05,
            far: 10.0,
        };
        let on = |x: u32, y: u32| {
            (x as f64 - centre.0).powi(2) + (y as f64 - centre.1).powi(2) <= radius * radius
        };
        let mask = GrayImage::from_fn(size.0, size.1, |x, y| {
            Luma([if on(x, y) { 255 } else { 0 }])
        });
        let depth = Gray32FImage::from_fn(size.0, size.1, |x, y| {
            Luma([if on(x, y) { 1.0 } else { 0.0 }])
        });
        let gray = GrayImage::from_fn(size.0, size.1, |x, y| {
            Luma([if on(x, y) { 200 } else { 0 }])
        });
        Frame::from_images(view, RgbaImage::new(size.0, size.1), gray, depth, mask)
            .expect("one size")
    }

    #[test]
    fn points_lie_on_the_disc_with_outward_normals_and_their_model_points() {
        let (cx, cy, r) = (160.0, 120.0, 60.0);
        let frame = disc_frame((320, 240), (cx, cy), r);
        let samples = sample(&frame, &SampleConfig::default());
        // The circumference is 377 px: one point per 8 px cell it crosses.
        assert!(samples.len() > 30, "{}", samples.len());
        for s in &samples {
            let radial = s.pixel - Vector2::new(cx, cy);
            // On the circle within a pixel, the normal within 12° of the radius.
            assert!((radial.norm() - r).abs() < 1.2, "{:?}", s.pixel);
            assert!(radial.normalize().dot(&s.normal) > 0.978, "{:?}", s.normal);
            // The model point is the contour pixel back-projected to 1 m.
            let n = frame.view.pinhole.to_normalised(s.pixel);
            assert!((s.m_w - Vector3::new(n.x, n.y, 1.0)).norm() < 1e-6);
            assert!(s.cov_w.iter().all(|v| v.is_finite()));
        }
        // Spread all around the circle: every 45° sector holds some.
        for k in 0..8 {
            let a0 = k as f64 * std::f64::consts::FRAC_PI_4 - std::f64::consts::PI;
            let n = samples
                .iter()
                .filter(|s| {
                    let a = (s.pixel.y - cy).atan2(s.pixel.x - cx);
                    a >= a0 && a < a0 + std::f64::consts::FRAC_PI_4
                })
                .count();
            assert!(n >= 3, "sector {k}: {n}");
        }
    }

    #[test]
    fn at_most_max_points_and_none_on_the_image_border() {
        // A disc cut by the left edge of the image: no point where the mask meets the edge.
        let frame = disc_frame((320, 240), (10.0, 120.0), 80.0);
        let cfg = SampleConfig {
            max_points: 10,
            ..SampleConfig::default()
        };
        let samples = sample(&frame, &cfg);
        assert!(
            !samples.is_empty() && samples.len() <= 10,
            "{}",
            samples.len()
        );
        assert!(samples.iter().all(|s| s.pixel.x > 3.0));
        let empty = disc_frame((64, 48), (-100.0, -100.0), 5.0);
        assert!(sample(&empty, &SampleConfig::default()).is_empty());
    }
}
