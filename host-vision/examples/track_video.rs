//! The tracker embedded in a program: a video tracked with the in-process core, one line per
//! frame, and the tracker's time per frame. `--decode-first` decodes the frames first, so that
//! the time is the tracker's alone (python/bench_overhead.py compares it with the Python
//! module's; python/tests/test_cube.py compares the poses).
//!
//! `cargo run --release -p host-vision --example track_video [--frames N] [--decode-first] [VIDEO CAMERA MODEL POSE]`

use std::time::{Duration, Instant};

use frames::{FrameInput, VideoOptions};
use tracker::{Event, TrackerBuilder, camera, model};

/// The shared cube video, or a video, its `camera.json`, a textured model and the start pose.
#[derive(clap::Parser)]
struct Args {
    /// Stop after this many frames.
    #[arg(long, default_value_t = usize::MAX)]
    frames: usize,
    /// Decode the frames before tracking them.
    #[arg(long)]
    decode_first: bool,
    #[arg(num_args = 4, value_names = ["VIDEO", "CAMERA", "MODEL", "POSE"], default_values = [
        "../shared/data/visp-cube/cube_video.mp4", "../shared/data/visp-cube/camera.json",
        "../shared/data/visp-cube/model/cube.obj", "../shared/data/visp-cube/frame0_pose.json"])]
    files: Vec<std::path::PathBuf>,
}

fn main() -> anyhow::Result<()> {
    let args = <Args as clap::Parser>::parse();
    let [video, camera, model, pose] = <&[_; 4]>::try_from(&args.files[..])?;
    let frames = FrameInput::Video(video.clone()).open(&VideoOptions::default())?;
    let mut tracker = TrackerBuilder::new(camera::read_camera_json(camera)?, model::load(model)?)
        .frame_rate_hz(frames.nominal_rate_hz().unwrap_or(30.0))
        .start_pose(camera::start_pose::read_start_pose(pose)?)
        .build()?;
    let frames = frames.take(args.frames);
    let frames: Box<dyn Iterator<Item = _>> = match args.decode_first {
        true => Box::new(frames.collect::<Vec<_>>().into_iter()),
        false => Box::new(frames),
    };
    let (mut busy, mut pushed) = (Duration::ZERO, 0usize);
    println!("# frame t_s tracked(1/0/-) c_w[m] q_cw[w x y z] (- where no pose)");
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
    let (t, n) = (done.tally.tracked, done.tally.judged);
    println!(
        "# tracked {t} of {n} frames judged: {:.1} %",
        100.0 * t as f64 / n.max(1) as f64
    );
    let ms = busy.as_secs_f64() * 1e3 / pushed.max(1) as f64;
    println!("# tracker time per frame (push_frame + poll): {ms:.3} ms over {pushed} frames");
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
