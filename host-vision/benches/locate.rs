//! The cold start's cost on the shared cube video (`../shared/data/visp-cube`): building the
//! viewpoint database (rendering, keypoints, back-projection; without writing it), and one
//! attempt (undistortion, ORB, matching through the index, RANSAC, verification) at 640×480
//! and at 320×240 (frame 0 halved, with the camera's intrinsics halved). The attempt's stages
//! are printed once per size. Skipped, saying so, without the video or ffmpeg.

use std::path::Path;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use frames::{FrameInput, VideoOptions};
use host_vision::camera::{Pinhole, pinhole_camera, read_camera_json};
use host_vision::locate::database::{Database, DatabaseConfig};
use host_vision::locate::{LocateConfig, Locator};
use host_vision::track::vision::{Vision, VisionOptions};
use image::imageops::{self, FilterType};

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/visp-cube");

fn locate(c: &mut Criterion) {
    let dir = Path::new(DATA);
    let video = dir.join("cube_video.mp4");
    if !video.exists() {
        eprintln!("locate bench skipped: {} is absent", video.display());
        return;
    }
    let frame = match FrameInput::Video(video.clone())
        .open(&VideoOptions::default())
        .map(|mut s| s.next())
    {
        Ok(Some(Ok(f))) => f.image,
        _ => {
            eprintln!("locate bench skipped: {} does not decode", video.display());
            return;
        }
    };
    let model = host_vision::model::load(&dir.join("model/cube.obj")).expect("cube model");
    let camera = read_camera_json(&dir.join("camera.json")).expect("camera.json");
    let config = DatabaseConfig::default();
    let db = Database::build(&model, &config, &mut |_, _| {}).expect("database");
    let bytes = db.to_bytes().map_or(0, |b| b.len());
    eprintln!(
        "database: {} renderings, {} keypoints, {:.2} MB on disk",
        db.views.len(),
        db.entries.len(),
        bytes as f64 / 1e6
    );

    let mut g = c.benchmark_group("locate");
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    g.bench_function("database build (160 renderings, 640x480)", |b| {
        b.iter(|| Database::build(&model, &config, &mut |_, _| {}).expect("database"))
    });

    let half = {
        let p = camera.pinhole;
        let pin = Pinhole::new(
            p.fx / 2.0,
            p.fy / 2.0,
            (p.cx + 0.5) / 2.0 - 0.5,
            (p.cy + 0.5) / 2.0 - 0.5,
        );
        pinhole_camera(camera.width / 2, camera.height / 2, pin).expect("half camera")
    };
    let small = imageops::resize(&frame, half.width, half.height, FilterType::Triangle);
    let locator = Locator::new(&db, LocateConfig::default());
    for (name, cam, img) in [("640x480", camera, &frame), ("320x240", half, &small)] {
        let mut options = VisionOptions::default();
        options.map.small_object_cells = true;
        let mut vision = Vision::new(cam, &model, options).expect("renderer");
        let (a, _) = locator.attempt(&mut vision, img, false).expect("attempt");
        let t = a.times;
        eprintln!(
            "attempt {name}: accepted {}, {} keypoints, {} matches, {} inliers, {} registered; detect {:.1} ms, match {:.1} ms, RANSAC {:.1} ms, verify {:.1} ms, choose {:.1} ms",
            a.accepted(),
            a.keypoints,
            a.matches,
            a.inliers,
            a.registered,
            t.detect * 1e3,
            t.matching * 1e3,
            t.ransac * 1e3,
            t.verify * 1e3,
            t.choose * 1e3
        );
        g.bench_function(format!("one attempt {name}"), |b| {
            b.iter(|| locator.attempt(&mut vision, img, false).expect("attempt"))
        });
    }
    g.finish();
}

criterion_group!(benches, locate);
criterion_main!(benches);
