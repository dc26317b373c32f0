//! Undistortion remap of the live image (`UndistortMap::remap_gray`, what `Vision::undistort`
//! runs every frame, and `remap_f32`) on the real 752×480 EuRoC frames with their real
//! calibration (`../shared/data/euroc-v101-micro/mav0/cam0/sensor.yaml`): the figure OpenCV's
//! reference script gives as "undistort remap, bilinear, u8" (`cv2.remap` with the map of
//! `initUndistortRectifyMap`, same intrinsics for the target, on the first 20 frames). When the
//! folder is absent: a synthetic texture and an EuRoC-like camera, with a note.

use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use host_vision::camera::{
    Camera, Distortion, Gray32FImage, Pinhole, UndistortMap, read_euroc_sensor_yaml,
};
use image::GrayImage;

const CAM0: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/data/euroc-v101-micro/mav0/cam0"
);

/// The real calibration and the first 20 frames (sorted by name), or a stand-in.
fn camera_and_frames() -> (Camera, Vec<GrayImage>) {
    let dir = Path::new(CAM0);
    let mut paths: Vec<_> = std::fs::read_dir(dir.join("data"))
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    paths.retain(|p| p.extension().is_some_and(|e| e == "png"));
    paths.sort();
    let frames: Vec<GrayImage> = paths
        .iter()
        .take(20)
        .map(|p| image::open(p).expect("a PNG frame").to_luma8())
        .collect();
    match read_euroc_sensor_yaml(&dir.join("sensor.yaml")) {
        Ok(calib) if !frames.is_empty() => (calib.camera, frames),
        _ => {
            eprintln!(
                "note: {} absent: a synthetic 752x480 texture and an EuRoC-like camera",
                dir.display()
            );
            let cam = Camera::new(
                752,
                480,
                Pinhole::new(458.654, 457.296, 367.215, 248.375),
                Distortion::RadTan {
                    k1: -0.28340811,
                    k2: 0.07395907,
                    p1: 0.00019359,
                    p2: 1.76187114e-05,
                    k3: 0.0,
                },
            )
            .expect("a valid camera");
            let img = GrayImage::from_fn(752, 480, |x, y| {
                let (fx, fy) = (x as f32, y as f32);
                let v = 128.0
                    + 60.0 * (fx * 0.13).sin() * (fy * 0.07).cos()
                    + 40.0 * ((fx + 2.0 * fy) * 0.05).sin();
                image::Luma([v as u8])
            });
            (cam, vec![img])
        }
    }
}

fn undistort(c: &mut Criterion) {
    let (cam, frames) = camera_and_frames();
    let map = UndistortMap::new(&cam).expect("an undistortion map");
    println!(
        "undistort {}x{} ({:?}), {} frames",
        cam.width,
        cam.height,
        cam.distortion,
        frames.len()
    );
    // Per frame over the frames, as the reference script times `cv2.remap`.
    c.bench_function("undistort_remap_gray_752x480_per_real_frame", |b| {
        b.iter_custom(|iters| {
            let start = Instant::now();
            for f in frames.iter().cycle().take(iters as usize) {
                black_box(map.remap_gray(black_box(f)).expect("same size"));
            }
            start.elapsed()
        })
    });
    let f32_img = Gray32FImage::from_fn(cam.width, cam.height, |x, y| {
        image::Luma([frames[0].get_pixel(x, y).0[0] as f32])
    });
    c.bench_function("undistort_remap_f32_752x480", |b| {
        b.iter(|| map.remap_f32(black_box(&f32_img)).expect("same size"))
    });
    c.bench_function("undistort_map_build_752x480", |b| {
        b.iter(|| UndistortMap::new(black_box(&cam)).expect("an undistortion map"))
    });
}

criterion_group!(benches, undistort);
criterion_main!(benches);
