//! Live tracking against a replay, side by side in one run (issue 35): how old a pose is when
//! it comes out, how many frames a live run drops, and what share it tracks.
//!
//! - The shared cube video (`../shared/data/visp-cube`, 640×480, 30 fps), vision-only from
//!   its frame-0 pose: replayed (every frame, in order, as fast as it goes) and played in real
//!   time as a camera would deliver it (`--pacing real-time`: a capture thread keeps only the
//!   newest frame); then in real time from a cold start (no pose), with the searches'
//!   database already in the cache, as on a user's second run.
//! - A synthetic dataset with an IMU (the paper's fast desktop sequence, 8 s, acc model),
//!   lock-step and real time: IMU sample → pose.
//!
//! Not a criterion bench: each figure is a distribution over one run, printed as a table.
//! `cargo bench -p host-vision --bench live`. Absolute times mean something only on the
//! machine that gave them; the cube runs are skipped, saying so, without the video.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use firmware_sim::sim::scenario::ScenarioName;
use frames::FrameInput;
use host_vision::camera::read_camera_json;
use host_vision::eval::{ensure_dataset, options_for};
use host_vision::start_pose::read_start_pose;
use host_vision::track::{self, FrameRow, Pacing, TrackOptions, TrackRun};
use protocol::ModelKind;
use tracker::latency::Percentiles;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/visp-cube");

/// The frames where the mug hides most of the cube (the cube-video test's "half visible"
/// are the others).
const BEHIND_THE_MUG: std::ops::Range<usize> = 548..750;

fn scratch(name: &str) -> PathBuf {
    std::env::temp_dir()
        .join("host-vision-bench-live")
        .join(name)
}

fn cube(dir: &Path, name: &str, pacing: Pacing, cold: bool) -> TrackOptions {
    let video = dir.join("cube_video.mp4");
    let mut o = TrackOptions::new(video.clone(), scratch(name));
    o.filter = ModelKind::Vision;
    o.frames = Some(FrameInput::Video(video));
    o.camera = Some(read_camera_json(&dir.join("camera.json")).expect("camera.json"));
    o.model = Some(dir.join("model/cube.obj"));
    o.tuning.expected_accel = track::config::OBJECT_IN_HAND_ACCEL;
    o.tuning.angular_noise = track::config::OBJECT_IN_HAND_ANGULAR_NOISE;
    if !cold {
        o.start.pose =
            Some(read_start_pose(&dir.join("frame0_pose.json")).expect("frame0_pose.json"));
    }
    o.cache = scratch("locate-cache");
    o.overlay_every = 0;
    o.overwrite = true;
    o.pacing = pacing;
    o
}

fn run(o: &TrackOptions) -> TrackRun {
    track::run(o, Arc::new(AtomicBool::new(false)), &mut |_, _, _, _| {})
        .unwrap_or_else(|e| panic!("{}: {e}", o.out.display()))
}

/// One line of the table.
struct Line {
    name: String,
    analysed: usize,
    dropped: usize,
    taken: Option<Percentiles>,
    sent: Option<Percentiles>,
    pose: Option<Percentiles>,
    sample: Option<Percentiles>,
    tracked: Option<f64>,
    first_tracked_s: Option<f64>,
}

impl Line {
    fn of(name: &str, run: &TrackRun) -> Self {
        let l = &run.summary.latency;
        let judged: Vec<&FrameRow> = run
            .frames
            .iter()
            .filter(|r| r.tracked.is_some() && !BEHIND_THE_MUG.contains(&r.index))
            .collect();
        let tracked = (!judged.is_empty()).then(|| {
            judged.iter().filter(|r| r.tracked == Some(true)).count() as f64 / judged.len() as f64
        });
        // From the first frame's capture to the pose of the first tracked frame.
        let first_tracked_s = run
            .frames
            .iter()
            .find(|r| r.tracked == Some(true))
            .map(|r| r.t + r.pose_ms.unwrap_or(0.0) * 1e-3);
        Self {
            name: name.into(),
            analysed: run.summary.frames,
            dropped: l.dropped_frames,
            taken: l.capture_to_taken,
            sent: l.capture_to_sent,
            pose: l.capture_to_pose,
            sample: l.sample_to_pose,
            tracked,
            first_tracked_s,
        }
    }
}

fn cell(p: &Option<Percentiles>) -> String {
    match p {
        Some(p) => format!("{:.1} / {:.1} / {:.1}", p.p50, p.p95, p.p99),
        None => "-".into(),
    }
}

fn print(lines: &[Line]) {
    println!(
        "\n| run | analysed | dropped | age when taken p95 / max [ms] | → sent p50/p95/p99 [ms] | → pose p50/p95/p99 [ms] | IMU sample → pose p50/p95/p99 [ms] | tracked (half-visible) | first tracked pose [s] |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for l in lines {
        println!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            l.name,
            l.analysed,
            l.dropped,
            l.taken
                .map_or("-".into(), |p| format!("{:.1} / {:.1}", p.p95, p.max)),
            cell(&l.sent),
            cell(&l.pose),
            cell(&l.sample),
            l.tracked
                .map_or("-".into(), |s| format!("{:.1} %", 100.0 * s)),
            l.first_tracked_s.map_or("-".into(), |t| format!("{t:.2}")),
        );
    }
}

fn main() {
    // `cargo test --benches` runs this with `--bench` absent: nothing to measure then.
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let mut lines = Vec::new();
    let dir = Path::new(DATA);
    if dir.join("cube_video.mp4").exists() {
        for (name, pacing) in [
            ("cube replay (lock-step)", Pacing::LockStep),
            ("cube real time, 30 fps", Pacing::RealTime),
        ] {
            let o = cube(dir, "cube", pacing, false);
            let r = run(&o);
            eprintln!("--- {name}\n{}", r.summary);
            lines.push(Line::of(name, &r));
        }
        // The searches' database first, as a user's second run finds it.
        let cold = cube(dir, "cube-cold", Pacing::RealTime, true);
        let model = host_vision::model::load(cold.model.as_ref().expect("model")).expect("model");
        host_vision::locate::database::Database::load_or_build(
            &model,
            &Default::default(),
            &cold.cache,
            &mut |_, _| {},
        )
        .expect("the searches' database");
        let r = run(&cold);
        eprintln!("--- cold\n{}", r.summary);
        lines.push(Line::of("cube real time, cold start", &r));
    } else {
        eprintln!(
            "live bench: the cube runs skipped: {} is absent (the shared data of issue 14)",
            dir.join("cube_video.mp4").display()
        );
    }
    let datasets = scratch("datasets");
    let ds = ensure_dataset(
        &datasets,
        ScenarioName::DesktopFast,
        Some(8.0),
        0,
        &mut |_, _| {},
    )
    .expect("the synthetic dataset");
    for (name, pacing) in [
        ("desktop-fast acc, lock-step", Pacing::LockStep),
        ("desktop-fast acc, real time", Pacing::RealTime),
    ] {
        let mut o = options_for(&ds, scratch("imu")).expect("the synthetic dataset's manifest");
        o.filter = ModelKind::Acc;
        o.overlay_every = 0;
        o.overwrite = true;
        o.pacing = pacing;
        let r = run(&o);
        eprintln!("--- {name}\n{}", r.summary);
        lines.push(Line::of(name, &r));
    }
    print(&lines);
    let _ = std::fs::remove_dir_all(scratch("cube"));
    let _ = std::fs::remove_dir_all(scratch("cube-cold"));
    let _ = std::fs::remove_dir_all(scratch("imu"));
}
