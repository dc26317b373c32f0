//! Overlay images: the undistorted live image with registered features as green crosses,
//! failed ones as red crosses at their predicted position, and the model's outline (yellow)
//! and axes drawn from the pose the core predicted (the augmentation an AR display would show
//! at that instant).

use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage};
use nalgebra::Vector3;

use super::vision::{FrameResult, prediction_pose};
use super::{Record, TrackError};
use crate::camera::Camera;
use frames::euroc::Dataset;

const GREEN: Rgb<u8> = Rgb([40, 230, 40]);
const RED: Rgb<u8> = Rgb([240, 40, 40]);
const OUTLINE: Rgb<u8> = Rgb([250, 220, 40]);
const AXES: [Rgb<u8>; 3] = [Rgb([255, 60, 60]), Rgb([60, 255, 60]), Rgb([80, 140, 255])];

/// Display scale of the overlays (small sensor images are hard to read at 1:1).
const SCALE: u32 = 2;

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

/// A line from `a` to `b` (pixels of `img`), clipped to the image, two pixels wide.
pub fn line(img: &mut RgbImage, a: [f64; 2], b: [f64; 2], c: Rgb<u8>) {
    if !a.iter().chain(&b).all(|v| v.is_finite()) {
        return;
    }
    let len = (b[0] - a[0]).hypot(b[1] - a[1]);
    // Lines far outside the image (a point just in front of the camera) are not drawn.
    if len > 8.0 * (img.width() + img.height()) as f64 {
        return;
    }
    let steps = len.ceil().max(1.0) as usize;
    for i in 0..=steps {
        let s = i as f64 / steps as f64;
        let x = (a[0] + (b[0] - a[0]) * s).round() as i64;
        let y = (a[1] + (b[1] - a[1]) * s).round() as i64;
        put(img, x, y, c);
        put(img, x + 1, y, c);
        put(img, x, y + 1, c);
    }
}

/// A diagonal cross of half size `r` at `p`.
pub fn cross(img: &mut RgbImage, p: [f64; 2], r: f64, c: Rgb<u8>) {
    line(img, [p[0] - r, p[1] - r], [p[0] + r, p[1] + r], c);
    line(img, [p[0] - r, p[1] + r], [p[0] + r, p[1] - r], c);
}

/// Draws one frame's overlay.
pub fn draw(result: &FrameResult, camera: &Camera, axes: (Vector3<f64>, f64)) -> Option<RgbImage> {
    let gray = result.image.as_ref()?;
    let (w, h) = gray.dimensions();
    let mut img = RgbImage::from_fn(w * SCALE, h * SCALE, |x, y| {
        let v = gray.get_pixel(x / SCALE, y / SCALE).0[0];
        Rgb([v, v, v])
    });
    let s = SCALE as f64;
    // Pixel centres: source (u, v) covers [sU, sU + s) in the scaled image.
    let at = |p: [f64; 2]| [(p[0] + 0.5) * s - 0.5, (p[1] + 0.5) * s - 0.5];
    // The model's outline where the core predicted it.
    for &[x, y] in &result.outline {
        let p = at([f64::from(x), f64::from(y)]);
        put(&mut img, p[0].round() as i64, p[1].round() as i64, OUTLINE);
        put(
            &mut img,
            p[0].round() as i64 + 1,
            p[1].round() as i64,
            OUTLINE,
        );
    }
    for f in &result.features {
        match f.registered {
            Ok(p) => cross(&mut img, at(p), 4.0, GREEN),
            Err(_) => cross(&mut img, at(f.predicted), 4.0, RED),
        }
    }
    if let Ok(pose) = prediction_pose(&result.job.prediction) {
        let (origin, length) = axes;
        let project = |p_w: Vector3<f64>| {
            let p_c = pose.world_to_camera(&p_w);
            camera.project(p_c).map(|px| at([px.x, px.y]))
        };
        if let Some(o) = project(origin) {
            for (k, colour) in AXES.iter().enumerate() {
                let mut tip = origin;
                tip[k] += length;
                if let Some(t) = project(tip) {
                    line(&mut img, o, t, *colour);
                }
            }
        }
    }
    Some(img)
}

/// Writes the overlays of every frame that kept its image into `dir`.
pub fn write_overlays(
    dir: &Path,
    dataset: &Dataset,
    record: &Record,
) -> Result<Vec<PathBuf>, TrackError> {
    let camera = dataset.camera.camera.ideal();
    let mut written = Vec::new();
    for (_, r) in &record.results {
        let Some(img) = draw(r, &camera, record.axes) else {
            continue;
        };
        if written.is_empty() {
            std::fs::create_dir_all(dir).map_err(|source| TrackError::Output {
                path: dir.to_owned(),
                source,
            })?;
        }
        let path = dir.join(format!("frame_{:06}.png", r.job.index));
        img.save(&path).map_err(|e| TrackError::Output {
            path: path.clone(),
            source: std::io::Error::other(e),
        })?;
        written.push(path);
    }
    Ok(written)
}
