//! The tracker with an IMU embedded in a program: a EuRoC-layout dataset (`mav0/imu0`,
//! `mav0/cam0`, its camera and model; default: the fast desktop sequence, synthesised into
//! `target/examples` on first use) replayed with the acc model and the cold start (no start
//! pose: the model is found in the frames). Every IMU sample is pushed, and each frame just
//! before the sample that triggered it; one line per frame, and the tracked share.
//!
//! `cargo run --release -p host-vision --example track_imu [DATASET]`

use anyhow::Context;
use firmware_sim::sim::scenario::ScenarioName;
use frames::euroc::Dataset;
use host_vision::{eval::ensure_synth, synth::SynthOptions};
use tracker::{Event, Frame, ImuSample, Start, TrackerBuilder};

fn main() -> anyhow::Result<()> {
    let dir = match std::env::args().nth(1) {
        Some(dir) => dir.into(),
        None => {
            let cache = std::path::Path::new("target/examples");
            let options = SynthOptions::new(ScenarioName::DesktopFast, cache.join("desktop-fast"));
            ensure_synth(cache, options, &mut |_, _| {})?
        }
    };
    let data = Dataset::open(&dir)?;
    let model = data
        .model
        .as_ref()
        .context("the dataset has no model/scene.obj")?;
    let model = host_vision::model::load(model)?;
    let mut tracker = TrackerBuilder::new(data.camera.camera, model)
        .imu(protocol::ModelKind::Acc, data.rig())
        .start(Start::Locate)
        .build()?;
    // Which frame each sample triggered (the frame's time is at or just before the sample's).
    let triggers: std::collections::HashMap<usize, usize> =
        data.triggers().into_iter().map(|(f, k)| (k, f)).collect();
    for (k, row) in data.imu.iter().enumerate() {
        if let Some(&f) = triggers.get(&k) {
            let image = image::open(&data.frames[f].path)?.to_luma8();
            tracker.push_frame(Frame::decoded(f, data.frames[f].stamp as i64, image))?;
        }
        let (t_ns, gyro, accel) = (row.stamp, row.gyro.into(), row.accel.into());
        tracker.push_imu(ImuSample { t_ns, gyro, accel })?;
        tracker.poll().for_each(|e| print_event(&e));
    }
    let done = tracker.finish();
    done.result?;
    done.events.iter().for_each(print_event);
    let (t, n) = (done.tally.tracked, done.tally.judged);
    println!(
        "# tracked {t} of {n} frames judged: {:.1} %",
        100.0 * t as f64 / n.max(1) as f64
    );
    Ok(())
}

/// A frame's line (index, time, tracked, camera position [m]), and the tracker's other news.
fn print_event(event: &Event) {
    match event {
        Event::Frame(f) => {
            let c = f
                .pose
                .map_or("-".into(), |p| format!("{:.3?}", p.c_w.as_slice()));
            let t = f.t_us as f64 * 1e-6;
            println!(
                "frame {} at {t:.3} s: tracked {:?}, c_w {c}",
                f.index, f.tracked
            );
        }
        Event::Pose(_) => {}
        other => println!("# {other:?}"),
    }
}
