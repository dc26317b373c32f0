//! The tracker embedded in a program: the shared cube video (or `VIDEO CAMERA MODEL POSE`:
//! a video, its `camera.json`, a textured OBJ/glTF and the start pose `cMo` as JSON) tracked
//! with the in-process core, one line per frame, and the time the tracker took per frame.
//! `--frames N` stops after N frames; `--decode-first` decodes them all before tracking, so
//! that the time per frame is the tracker's alone (no ffmpeg beside it). The Python module's
//! tests compare their poses with these lines, and its overhead bench its time
//! (python/bench_overhead.py).
//!
//! `cargo run --release -p host-vision --example track_video [--frames N] [--decode-first] [VIDEO CAMERA MODEL POSE]`

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use host_vision::frames::{FrameInput, VideoOptions};
use tracker::{Event, TrackerBuilder, camera, model};

fn main() -> anyhow::Result<()> {
    let data = PathBuf::from("../shared/data/visp-cube");
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let limit = match args.iter().position(|a| a == "--frames") {
        Some(i) => {
            let n = args.get(i + 1).context("--frames needs a number")?;
            let n: usize = n.parse().with_context(|| format!("--frames {n}"))?;
            args.drain(i..i + 2);
            n
        }
        None => usize::MAX,
    };
    let decode_first = match args.iter().position(|a| a == "--decode-first") {
        Some(i) => {
            args.remove(i);
            true
        }
        None => false,
    };
    let [video, camera, model, pose] = match <[String; 4]>::try_from(args) {
        Ok(given) => given.map(PathBuf::from),
        Err(_) => [
            "cube_video.mp4",
            "camera.json",
            "model/cube.obj",
            "frame0_pose.json",
        ]
        .map(|f| data.join(f)),
    };
    let frames = FrameInput::Video(video).open(&VideoOptions::default())?;
    let mut tracker = TrackerBuilder::new(camera::read_camera_json(&camera)?, model::load(&model)?)
        .frame_rate_hz(frames.nominal_rate_hz().unwrap_or(30.0))
        .start_pose(camera::start_pose::read_start_pose(&pose)?)
        .build()?;
    println!("# frame t_s tracked(1/0/-) c_w[m] q_cw[w x y z] (- where no pose)");
    let mut busy = Duration::ZERO;
    let mut pushed = 0usize;
    let frames: Box<dyn Iterator<Item = _>> = if decode_first {
        let all: Vec<_> = frames.take(limit).collect();
        Box::new(all.into_iter())
    } else {
        Box::new(frames.take(limit))
    };
    for frame in frames {
        let frame = frame?;
        let started = Instant::now();
        tracker.push_frame(frame.into())?;
        let events: Vec<Event> = tracker.poll().collect();
        busy += started.elapsed();
        pushed += 1;
        events.iter().for_each(print_frame);
    }
    let done = tracker.finish();
    done.result?;
    // The last frames' reports come with the end.
    done.events.iter().for_each(print_frame);
    let tracker::judge::Tally { tracked, judged } = done.tally;
    let share = 100.0 * tracked as f64 / judged.max(1) as f64;
    println!("# tracked {tracked} of {judged} frames judged: {share:.1} %");
    println!(
        "# tracker time per frame (push_frame + poll): {:.3} ms over {pushed} frames",
        busy.as_secs_f64() * 1e3 / pushed.max(1) as f64
    );
    Ok(())
}

/// A frame's line: index, time, tracked, and the pose where there is one.
fn print_frame(event: &Event) {
    let Event::Frame(f) = event else { return };
    let tracked = f.tracked.map_or("-", |t| if t { "1" } else { "0" });
    let pose = f.pose.map_or("- - - - - - -".into(), |p| {
        let (c, q) = (p.c_w, p.q_cw.quaternion());
        format!(
            "{:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
            c.x, c.y, c.z, q.w, q.i, q.j, q.k
        )
    });
    println!("{} {:.6} {tracked} {pose}", f.index, f.t_us as f64 * 1e-6);
}
