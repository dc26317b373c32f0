//! Frames per second of the vision-only pipeline on the shared cube video
//! (`../shared/data/visp-cube`, 640×480): the first 150 frames tracked from the frame-0 pose
//! (prediction, rendering, FAST on demand, photometric KLT, correspondences, the core's
//! update over the simulated board's pty, and the frame's judgement: a second rendering and
//! its correlation), with the ffmpeg decoding counted (`--video`) and not counted (the same
//! frames decoded once beforehand, [`FrameInput::Decoded`]), side by side in one run. Each
//! sample is one tracking run; its time is the run's own wall time (`summary.wall_s`: from the
//! handshake to the last frame, without starting the renderer and the link). Skipped, saying
//! so, without the video or ffmpeg.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use frames::{FrameInput, VideoOptions};
use host_vision::camera::read_camera_json;
use host_vision::start_pose::read_start_pose;
use host_vision::track::{self, TrackOptions};
use protocol::ModelKind;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/visp-cube");
const FRAMES: usize = 150;

fn options(input: FrameInput, out: PathBuf) -> TrackOptions {
    let dir = Path::new(DATA);
    let mut o = TrackOptions::new(input.path().to_owned(), out);
    o.filter = ModelKind::Vision;
    o.frames = Some(input);
    o.camera = Some(read_camera_json(&dir.join("camera.json")).expect("camera.json"));
    o.model = Some(dir.join("model/cube.obj"));
    o.start.pose = Some(read_start_pose(&dir.join("frame0_pose.json")).expect("frame0_pose.json"));
    o.tuning.expected_accel = track::config::OBJECT_IN_HAND_ACCEL;
    o.tuning.angular_noise = track::config::OBJECT_IN_HAND_ANGULAR_NOISE;
    o.overlay_every = 0;
    o.overwrite = true;
    o.max_frames = Some(FRAMES);
    o
}

fn vision_only(c: &mut Criterion) {
    let video = Path::new(DATA).join("cube_video.mp4");
    if !video.exists() {
        eprintln!(
            "vision_only bench skipped: {} is absent (the shared data of issue 14)",
            video.display()
        );
        return;
    }
    let input = FrameInput::Video(video.clone());
    let frames: Vec<_> = match input
        .open(&VideoOptions::default())
        .and_then(|s| s.take(FRAMES).collect::<Result<Vec<_>, _>>())
    {
        Ok(f) => f,
        Err(e) => {
            eprintln!("vision_only bench skipped: {e}");
            return;
        }
    };
    let decoded = FrameInput::Decoded {
        name: video.clone(),
        frames: Arc::new(frames),
        fps: Some(30.0),
    };
    let out = std::env::temp_dir().join("host-vision-bench-vision-only");
    let mut group = c.benchmark_group("vision_only");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(60))
        .throughput(Throughput::Elements(FRAMES as u64));
    for (name, input) in [
        ("cube_150_frames_with_decoding", input),
        ("cube_150_frames_decoded_beforehand", decoded),
    ] {
        let o = options(input, out.clone());
        group.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    let run =
                        track::run(&o, Arc::new(AtomicBool::new(false)), &mut |_, _, _, _| {})
                            .expect("the cube video tracks");
                    assert_eq!(run.summary.frames, FRAMES);
                    total += Duration::from_secs_f64(run.summary.wall_s);
                }
                total
            })
        });
    }
    group.finish();
    let _ = std::fs::remove_dir_all(&out);
}

criterion_group!(benches, vision_only);
criterion_main!(benches);
