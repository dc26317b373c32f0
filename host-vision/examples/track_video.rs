//! The tracker embedded in a program: a video (default: the shared cube video, else `VIDEO
//! CAMERA MODEL POSE`: its `camera.json`, a textured OBJ/glTF, the start pose `cMo` as JSON)
//! tracked with the in-process core, one line per frame, and the tracker's time per frame.
//! `--frames N` stops after N frames; `--decode-first` decodes them first, so that the time is
//! the tracker's alone (python/bench_overhead.py compares it; python/tests/test_cube.py the poses).
//!
//! `cargo run --release -p host-vision --example track_video [--frames N] [--decode-first] [VIDEO CAMERA MODEL POSE]`

use std::time::{Duration, Instant};

use anyhow::Context;
use host_vision::frames::{FrameInput, VideoOptions};
use tracker::{Event, TrackerBuilder, camera, model};

fn main() -> anyhow::Result<()> {
    let (mut limit, mut decode_first, mut paths) = (usize::MAX, false, Vec::new());
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--frames" => {
                limit = args
                    .next()
                    .context("--frames N")?
                    .parse()
                    .context("--frames N")?
            }
            "--decode-first" => decode_first = true,
            _ => paths.push(std::path::PathBuf::from(a)),
        }
    }
    let data = std::path::Path::new("../shared/data/visp-cube");
    let [video, camera, model, pose] = <[_; 4]>::try_from(paths).unwrap_or_else(|_| {
        [
            "cube_video.mp4",
            "camera.json",
            "model/cube.obj",
            "frame0_pose.json",
        ]
        .map(|f| data.join(f))
    });
    let frames = FrameInput::Video(video).open(&VideoOptions::default())?;
    let mut tracker = TrackerBuilder::new(camera::read_camera_json(&camera)?, model::load(&model)?)
        .frame_rate_hz(frames.nominal_rate_hz().unwrap_or(30.0))
        .start_pose(camera::start_pose::read_start_pose(&pose)?)
        .build()?;
    let frames = frames.take(limit);
    let frames: Box<dyn Iterator<Item = _>> = match decode_first {
        true => Box::new(frames.collect::<Vec<_>>().into_iter()),
        false => Box::new(frames),
    };
    println!("# frame t_s tracked(1/0/-) c_w[m] q_cw[w x y z] (- where no pose)");
    let (mut busy, mut pushed) = (Duration::ZERO, 0usize);
    for frame in frames {
        let started = Instant::now();
        tracker.push_frame(frame?.into())?;
        let events: Vec<Event> = tracker.poll().collect();
        (busy, pushed) = (busy + started.elapsed(), pushed + 1);
        events.iter().for_each(print_frame);
    }
    let done = tracker.finish();
    done.result?;
    done.events.iter().for_each(print_frame); // the last frames' reports come with the end
    let tracker::judge::Tally { tracked, judged } = done.tally;
    println!(
        "# tracked {tracked} of {judged} frames judged: {:.1} %",
        100.0 * tracked as f64 / judged.max(1) as f64
    );
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
