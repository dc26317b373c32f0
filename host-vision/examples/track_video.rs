//! The tracker embedded in a program: the shared cube video (or `VIDEO CAMERA MODEL POSE`:
//! a video, its `camera.json`, a textured OBJ/glTF and the start pose `cMo` as JSON) tracked
//! with the in-process core, one pose printed per frame.
//!
//! `cargo run --release -p host-vision --example track_video [VIDEO CAMERA MODEL POSE]`

use std::path::PathBuf;

use firmware_sim::board::Precision;
use host_vision::frames::{FrameInput, VideoOptions};
use tracker::{CoreLink, Event, LinkSpec, Start, Tracker, TrackerConfig};

fn main() -> anyhow::Result<()> {
    let data = PathBuf::from("../shared/data/visp-cube");
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [video, camera, model, pose] = match <[PathBuf; 4]>::try_from(args) {
        Ok(given) => given,
        Err(_) => [
            "cube_video.mp4",
            "camera.json",
            "model/cube.obj",
            "frame0_pose.json",
        ]
        .map(|f| data.join(f)),
    };
    let frames = FrameInput::Video(video).open(&VideoOptions::default())?;
    let mut config = TrackerConfig::new(
        camera::read_camera_json(&camera)?,
        frames.nominal_rate_hz().unwrap_or(30.0),
        locate::database::default_cache_dir(),
    );
    config.start = Start::Camera(host_vision::start_pose::read_start_pose(&pose)?);
    let core = CoreLink::open(&LinkSpec::InProcess(Precision::F32))?;
    let mut tracker = Tracker::new(config, &model::load(&model)?, core)?;
    println!("# frame t_s tracked c_w[m] q_cw[w x y z] (frames with a pose)");
    for frame in frames {
        tracker.push_frame(frame?.into())?;
        for event in tracker.poll() {
            let Event::Frame(f) = event else { continue };
            let Some((c, q)) = f.pose.map(|p| (p.c_w, *p.q_cw.quaternion())) else {
                continue;
            };
            let (t, tracked) = (f.t_us as f64 * 1e-6, u8::from(f.tracked == Some(true)));
            let (c, q) = ([c.x, c.y, c.z], [q.w, q.i, q.j, q.k]);
            println!("{} {t:.3} {tracked} {c:.4?} {q:.4?}", f.index);
        }
    }
    let done = tracker.finish();
    done.result?;
    let (tracked, judged) = done.record.tracked_count(&vision::TrackedRule::default());
    let share = 100.0 * tracked as f64 / judged.max(1) as f64;
    println!("# tracked {tracked} of {judged} frames judged: {share:.1} %");
    Ok(())
}
