//! Feature costs on a 752×480 EuRoC frame (`../shared/data`; a synthetic texture when the
//! folder is absent): FAST-9 + non-maximum suppression (also per frame over all the real
//! frames, the figure OpenCV's reference script gives, and the scalar reference), pyramid build, rendering preparation
//! (anti-aliasing blur + image and mask pyramids), and one photometric KLT registration with
//! the default window (15×15) and levels (4), starting 7 px off with a contrast and
//! brightness change.

use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use host_vision::features::fast;
use host_vision::features::gray::{GrayF32, Mask};
use host_vision::features::grid::{self, GridConfig};
use host_vision::features::klt::{self, KltConfig};
use host_vision::features::pyramid::{Pyramid, TemplatePyramid};
use image::GrayImage;

#[path = "../tests/klt_cases/mod.rs"]
mod klt_cases;

fn frame() -> GrayImage {
    let path = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/euroc-v101-micro/mav0/cam0/data/1403715273262142976.png"
    ));
    match image::open(path) {
        Ok(img) => img.to_luma8(),
        Err(_) => {
            eprintln!("note: {} absent, using a synthetic texture", path.display());
            GrayImage::from_fn(752, 480, |x, y| {
                let (fx, fy) = (x as f32, y as f32);
                let v = 128.0
                    + 60.0 * (fx * 0.13).sin() * (fy * 0.07).cos()
                    + 40.0 * ((fx + 2.0 * fy) * 0.05).sin();
                image::Luma([v as u8])
            })
        }
    }
}

/// All the real frames of the micro sequence, sorted by name, or none when the folder is absent.
fn all_frames() -> Vec<GrayImage> {
    let dir = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/euroc-v101-micro/mav0/cam0/data"
    ));
    let mut paths: Vec<_> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    paths.retain(|p| p.extension().is_some_and(|e| e == "png"));
    paths.sort();
    paths
        .iter()
        .map(|p| image::open(p).expect("a PNG frame").to_luma8())
        .collect()
}

fn fast_on_all_frames(c: &mut Criterion) {
    println!(
        "kernels: {} copy (TRACKER_ISA=baseline runs the baseline's)",
        isa::name()
    );
    let frames = all_frames();
    if frames.is_empty() {
        eprintln!(
            "SKIPPED: fast9_nms_per_real_frame: no frames under ../shared/data/euroc-v101-micro"
        );
        return;
    }
    let corners: usize = frames.iter().map(|f| fast::detect(f, 20, true).len()).sum();
    println!(
        "{} real frames, {:.1} FAST corners per frame (threshold 20, NMS)",
        frames.len(),
        corners as f64 / frames.len() as f64
    );
    c.bench_function("fast9_nms_per_real_frame", |b| {
        b.iter_custom(|iters| time_frames(&frames, iters, fast::detect))
    });
    c.bench_function("fast9_nms_per_real_frame_scalar_reference", |b| {
        b.iter_custom(|iters| time_frames(&frames, iters, fast::reference::detect))
    });
}

/// `iters` FAST + NMS runs, one frame each, cycling through all of them: the time per frame
/// over the whole sequence, as OpenCV's reference script reports it.
fn time_frames(
    frames: &[GrayImage],
    iters: u64,
    detect: fn(&GrayImage, u8, bool) -> Vec<fast::Corner>,
) -> Duration {
    let start = Instant::now();
    for f in frames.iter().cycle().take(iters as usize) {
        black_box(detect(black_box(f), 20, true));
    }
    start.elapsed()
}

fn features(c: &mut Criterion) {
    let img = frame();
    println!(
        "image {}x{}, {} FAST corners (threshold 20, NMS)",
        img.width(),
        img.height(),
        fast::detect(&img, 20, true).len()
    );
    c.bench_function("fast9_nms_752x480", |b| {
        b.iter(|| fast::detect(black_box(&img), 20, true))
    });

    let cfg = KltConfig::default();
    let base = GrayF32::from_gray8(&img).unwrap();
    c.bench_function("pyramid_build_752x480_4_levels", |b| {
        b.iter(|| cfg.target_pyramid(black_box(base.clone())))
    });
    let mask = Mask::full(base.width(), base.height()).unwrap();
    c.bench_function("template_prepare_752x480_blur1_4_levels", |b| {
        b.iter(|| {
            TemplatePyramid::build(
                black_box(base.clone()),
                mask.clone(),
                cfg.levels,
                cfg.template_sigma(1.0),
            )
        })
    });

    // Live image: the frame shifted by (7, −3) px (integer, cheap to make), contrast 0.7,
    // brightness +25.
    let (w, h) = (base.width(), base.height());
    let live: Vec<f32> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as isize - 7, (i / w) as isize + 3);
            let v = base
                .get(
                    x.clamp(0, w as isize - 1) as usize,
                    y.clamp(0, h as isize - 1) as usize,
                )
                .unwrap();
            (v - 25.0) / 0.7
        })
        .collect();
    let target = cfg.target_pyramid(GrayF32::new(w, h, live).unwrap());
    let tmpl =
        TemplatePyramid::build(base.clone(), mask, cfg.levels, cfg.template_sigma(1.0)).unwrap();
    let points: Vec<[f64; 2]> = grid::extract(
        &img,
        None,
        &[],
        &GridConfig {
            cell_size: 48,
            border: 40,
            ..GridConfig::default()
        },
    )
    .unwrap()
    .iter()
    .map(|c| [c.x as f64, c.y as f64])
    .collect();
    let ok = points
        .iter()
        .filter(|p| {
            klt::register(&tmpl.image, Some(&tmpl.mask), &target, **p, [0.0; 2], &cfg).is_ok()
        })
        .count();
    println!("KLT: {ok}/{} features registered", points.len());
    let mut k = 0;
    c.bench_function("klt_photometric_per_feature_15x15_4_levels", |b| {
        b.iter(|| {
            k = (k + 1) % points.len();
            klt::register(
                &tmpl.image,
                Some(&tmpl.mask),
                &target,
                black_box(points[k]),
                [0.0; 2],
                &cfg,
            )
        })
    });
}

/// The photometric KLT (default window and levels) on the first of OpenCV's cases
/// (`tests/klt_cases`: the frame, its shift by (7.3, −4.6) px, its 200 strongest corners, a
/// zero guess), per feature as the reference script's marginal LK figure; also the reference
/// implementation, and the failures under every illumination change.
fn klt_on_opencv_cases(c: &mut Criterion) {
    let Some(cases) = klt_cases::load() else {
        eprintln!("SKIPPED: klt_opencv_case: no frames");
        return;
    };
    let cfg = KltConfig::default();
    let case = &cases[0];
    let tmpl = Pyramid::build_smoothed(
        GrayF32::from_gray8(&case.template).unwrap(),
        cfg.levels,
        cfg.template_sigma(0.0),
    );
    let targets: Vec<Pyramid> = case
        .targets
        .iter()
        .map(|t| cfg.target_pyramid(GrayF32::from_gray8(t).unwrap()))
        .collect();
    for ((name, _, _), target) in klt_cases::VARIANTS.iter().zip(&targets) {
        let found: Vec<_> = case
            .points
            .iter()
            .map(|&p| {
                klt::register(&tmpl, None, target, p, [0.0; 2], &cfg)
                    .ok()
                    .map(|r| r.position)
            })
            .collect();
        let (failed, _) = klt_cases::score(&case.points, &found);
        println!(
            "{}: {name}: {failed}/{} failures",
            case.name,
            case.points.len()
        );
    }
    let points = &case.points;
    let mut k = 0;
    c.bench_function("klt_photometric_per_feature_opencv_case", |b| {
        b.iter(|| {
            k = (k + 1) % points.len();
            klt::register(
                &tmpl,
                None,
                &targets[0],
                black_box(points[k]),
                [0.0; 2],
                &cfg,
            )
        })
    });
    c.bench_function("klt_photometric_per_feature_opencv_case_reference", |b| {
        b.iter(|| {
            k = (k + 1) % points.len();
            klt::reference::register(
                &tmpl,
                None,
                &targets[0],
                black_box(points[k]),
                [0.0; 2],
                &cfg,
            )
        })
    });
}

criterion_group!(benches, fast_on_all_frames, features, klt_on_opencv_cases);
criterion_main!(benches);
