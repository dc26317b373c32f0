//! Decoding speed of the frame sources: the shared cube video (640×480 H.264, 989 frames,
//! `../shared/data/visp-cube/cube_video.mp4`) through the ffmpeg pipe, every frame to its
//! grey image. Criterion's throughput is frames per second. Skipped, saying so, when the
//! video or ffmpeg is absent.

use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use frames::{FrameInput, VideoOptions};

const VIDEO: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/data/visp-cube/cube_video.mp4"
);

fn decode(c: &mut Criterion) {
    let input = FrameInput::Video(VIDEO.into());
    if !Path::new(VIDEO).exists() {
        eprintln!("decode bench skipped: {VIDEO} is absent (the shared data of issue 14)");
        return;
    }
    // One full pass first: counts the frames and fails clearly without ffmpeg.
    let frames = match input
        .open(&VideoOptions::default())
        .and_then(|s| s.collect::<Result<Vec<_>, _>>())
    {
        Ok(f) => f.len(),
        Err(e) => {
            eprintln!("decode bench skipped: {e}");
            return;
        }
    };
    let mut group = c.benchmark_group("decode");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(20))
        .throughput(Throughput::Elements(frames as u64));
    group.bench_function("cube_video_640x480_ffmpeg", |b| {
        b.iter(|| {
            let mut n = 0usize;
            for frame in input.open(&VideoOptions::default()).unwrap() {
                black_box(frame.unwrap());
                n += 1;
            }
            assert_eq!(n, frames);
        })
    });
    group.finish();
}

criterion_group!(benches, decode);
criterion_main!(benches);
