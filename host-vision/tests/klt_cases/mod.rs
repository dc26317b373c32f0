//! The KLT cases of OpenCV's reference script (`../shared/tools/opencv-reference/`): real
//! EuRoC frames, the target the frame shifted by (7.3, −4.6) px and its illumination changed,
//! and the 200 strongest FAST corners to register from a zero guess. Shared by
//! `tests/features_klt.rs` (the failure rates) and `benches/features.rs` (the time per feature).
//!
//! With `KLT_CASES=DIR` the cases the script wrote with `--out DIR` are read, so that both sides
//! register exactly the same images and points; otherwise they are made here the same way
//! (FAST corners are identical to OpenCV's; the shift's bilinear interpolation differs from
//! `warpAffine`'s 5-bit fixed point by at most one gray level).

#![allow(dead_code)]

use std::path::{Path, PathBuf};

use host_vision::features::fast;
use image::GrayImage;

/// The script's shift of the target, px.
pub const SHIFT: [f64; 2] = [7.3, -4.6];
/// Corners per frame.
const POINTS: usize = 200;
/// Distance from the border of a corner and of its shifted position, px.
const MARGIN: f64 = 24.0;
/// A registration further than this from the truth counts as a failure (as in the script).
pub const FAIL_PX: f64 = 1.0;

/// The illumination changes `J ↦ clip(c·J + b)`, named as the script names them.
pub const VARIANTS: [(&str, f64, f64); 6] = [
    ("none", 1.0, 0.0),
    ("c0.5b40", 0.5, 40.0),
    ("c1.8b-30", 1.8, -30.0),
    ("b40", 1.0, 40.0),
    ("c0.4b60", 0.4, 60.0),
    ("c2.5b-60", 2.5, -60.0),
];

/// One frame's case: the template frame, its targets in [`VARIANTS`] order, the points.
pub struct Case {
    pub name: String,
    pub template: GrayImage,
    pub targets: Vec<GrayImage>,
    pub points: Vec<[f64; 2]>,
}

fn frames_dir() -> PathBuf {
    Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/euroc-v101-micro/mav0/cam0/data"
    ))
    .to_path_buf()
}

/// Every tenth frame of the micro sequence, as the script takes them; `None` (with a message)
/// when neither `KLT_CASES` nor the frames are there.
pub fn load() -> Option<Vec<Case>> {
    if let Ok(dir) = std::env::var("KLT_CASES") {
        return Some(read_written(Path::new(&dir)));
    }
    let mut paths: Vec<PathBuf> = std::fs::read_dir(frames_dir())
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    if paths.is_empty() {
        println!(
            "SKIPPED: no frames under {}: the OpenCV KLT cases are not run",
            frames_dir().display()
        );
        return None;
    }
    paths.sort();
    Some(
        paths
            .iter()
            .enumerate()
            .step_by(10)
            .map(|(k, p)| {
                let img = image::open(p)
                    .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
                    .to_luma8();
                make(format!("f{k:03}"), img)
            })
            .collect(),
    )
}

/// The cases the script wrote: `fNNN_I.png`, `fNNN_<variant>.png`, `fNNN_pts.csv`.
fn read_written(dir: &Path) -> Vec<Case> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("KLT_CASES={}: {e}", dir.display()))
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let n = e.file_name().to_string_lossy().to_string();
            n.strip_suffix("_pts.csv").map(str::to_string)
        })
        .collect();
    names.sort();
    assert!(
        !names.is_empty(),
        "KLT_CASES={}: no *_pts.csv",
        dir.display()
    );
    let png = |n: &str| {
        let p = dir.join(format!("{n}.png"));
        image::open(&p)
            .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
            .to_luma8()
    };
    names
        .into_iter()
        .map(|name| {
            let csv = dir.join(format!("{name}_pts.csv"));
            let text =
                std::fs::read_to_string(&csv).unwrap_or_else(|e| panic!("{}: {e}", csv.display()));
            let points = text
                .lines()
                .filter(|l| !l.trim().is_empty())
                .map(|l| {
                    let v: Vec<f64> = l
                        .split(',')
                        .map(|s| {
                            s.trim()
                                .parse()
                                .unwrap_or_else(|e| panic!("{}: {l:?}: {e}", csv.display()))
                        })
                        .collect();
                    assert_eq!(v.len(), 2, "{}: {l:?}", csv.display());
                    [v[0], v[1]]
                })
                .collect();
            Case {
                template: png(&format!("{name}_I")),
                targets: VARIANTS
                    .iter()
                    .map(|(v, _, _)| png(&format!("{name}_{v}")))
                    .collect(),
                points,
                name,
            }
        })
        .collect()
}

/// The case of one frame, made as the script makes it.
fn make(name: String, img: GrayImage) -> Case {
    let (w, h) = (img.width() as f64, img.height() as f64);
    let inside = |x: f64, y: f64| MARGIN <= x && x < w - MARGIN && MARGIN <= y && y < h - MARGIN;
    let mut corners: Vec<_> = fast::detect(&img, 20, true)
        .into_iter()
        .filter(|c| {
            let (x, y) = (c.x as f64, c.y as f64);
            inside(x, y) && inside(x + SHIFT[0], y + SHIFT[1])
        })
        .collect();
    // Stable, by descending score, as the script's `list.sort`.
    corners.sort_by_key(|c| std::cmp::Reverse(c.score));
    let points = corners
        .iter()
        .take(POINTS)
        .map(|c| [c.x as f64, c.y as f64])
        .collect();
    let shifted = shift(&img);
    let targets = VARIANTS
        .iter()
        .map(|&(_, c, b)| {
            GrayImage::from_fn(img.width(), img.height(), |x, y| {
                let v = shifted[(y * img.width() + x) as usize];
                image::Luma([(c * v + b).clamp(0.0, 255.0).round_ties_even() as u8])
            })
        })
        .collect();
    Case {
        name,
        template: img,
        targets,
        points,
    }
}

/// `J(x) = I(x − SHIFT)`, bilinear, the border replicated (as `warpAffine` with
/// `BORDER_REPLICATE`), rounded to gray levels.
fn shift(img: &GrayImage) -> Vec<f64> {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let px = |x: i64, y: i64| img.get_pixel(x.clamp(0, w - 1) as u32, y.clamp(0, h - 1) as u32)[0];
    let mut out = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let (sx, sy) = (x as f64 - SHIFT[0], y as f64 - SHIFT[1]);
            let (x0, y0) = (sx.floor(), sy.floor());
            let (fx, fy) = (sx - x0, sy - y0);
            let (x0, y0) = (x0 as i64, y0 as i64);
            let v = (1.0 - fy) * ((1.0 - fx) * px(x0, y0) as f64 + fx * px(x0 + 1, y0) as f64)
                + fy * ((1.0 - fx) * px(x0, y0 + 1) as f64 + fx * px(x0 + 1, y0 + 1) as f64);
            out.push(v.round());
        }
    }
    out
}

/// Failures (an error, or further than [`FAIL_PX`] from the truth) and the errors of the
/// others, of one target's registrations.
pub fn score(points: &[[f64; 2]], positions: &[Option<[f64; 2]>]) -> (usize, Vec<f64>) {
    let mut failures = 0;
    let mut errors = Vec::new();
    for (p, r) in points.iter().zip(positions) {
        match r {
            Some(q) => {
                let e = (q[0] - p[0] - SHIFT[0]).hypot(q[1] - p[1] - SHIFT[1]);
                if e > FAIL_PX {
                    failures += 1;
                } else {
                    errors.push(e);
                }
            }
            None => failures += 1,
        }
    }
    (failures, errors)
}
