//! The tracker's memory over a long run (issue 57): a synthetic sequence with its IMU at 200 Hz
//! (the fast desktop scenario at its nominal 30 s, 25 Hz camera, synthesised once into
//! `target/memory-bench`) played again and again, every frame and sample pushed in order (a
//! replay: each frame analysed, as fast as the machine goes), for an hour of sensor time. Every
//! simulated minute it prints the process's resident memory (`VmRSS`), and at the end its
//! growth from the first minute and the peak (`VmHWM`).
//!
//! The sequence starts and ends at rest at the same pose (its figure eight fades in and out),
//! so the laps join without a jump. The tracker starts cold (it finds the model first).
//! `MEMORY_EVENTS=1` prints every event but the frames' and the poses'.
//!
//! `cargo bench -p host-vision --bench memory` (an hour of sensor time);
//! `-- --minutes M` for another length. The peak of the cube example alone:
//! `/usr/bin/time -v cargo run --release -p host-vision --example track_video`.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use firmware_sim::sim::scenario::ScenarioName;
use frames::euroc::Dataset;
use host_vision::eval::ensure_synth;
use host_vision::synth::SynthOptions;
use protocol::ModelKind;
use tracker::{Frame, ImuSample, Start, TrackerBuilder};

/// A field of `/proc/self/status` [MB].
fn status_mb(field: &str) -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(field))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let minutes: f64 = match args.iter().position(|a| a == "--minutes") {
        Some(i) => args.get(i + 1).ok_or("--minutes needs a number")?.parse()?,
        None => 60.0,
    };
    let cache = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/memory-bench");
    let options = SynthOptions {
        rates: Some((200.0, 8)),
        overwrite: true,
        ..SynthOptions::new(ScenarioName::DesktopFast, cache.join("desktop-fast-200hz"))
    };
    let dir = ensure_synth(&cache, options, &mut |_, _| {})?;
    let dataset = Dataset::open(&dir)?;
    let model = host_vision::model::load(dataset.model.as_ref().ok_or("no model")?)?;
    let images: Vec<_> = dataset
        .frames
        .iter()
        .map(|f| image::open(&f.path).map(|i| i.to_luma8()))
        .collect::<Result<_, _>>()?;
    let triggers: BTreeMap<usize, usize> = dataset
        .triggers()
        .into_iter()
        .map(|(f, k)| (k, f))
        .collect();
    let imu = &dataset.imu;
    let (first, last) = (imu[0].stamp, imu[imu.len() - 1].stamp);
    let period_ns = (1e9 / dataset.imu_rate_hz) as u64;
    let span_ns = last - first + period_ns;
    let mut tracker = TrackerBuilder::new(dataset.camera.camera, model)
        .imu(ModelKind::Acc, dataset.rig())
        // The cold start: the tracker finds the model first, and again after any loss.
        .start(Start::Locate)
        .cache(cache.join("database"))
        .build()?;
    println!(
        "memory: {} of {:.0} s at {:.0} Hz IMU, {} frames, played for {minutes} min of sensor time",
        dir.display(),
        span_ns as f64 * 1e-9,
        dataset.imu_rate_hz,
        images.len()
    );
    println!("| sensor time [min] | frames | VmRSS [MB] | wall [s] |");
    println!("|---|---|---|---|");
    let began = Instant::now();
    let end_ns = (minutes * 60e9) as u64;
    let (mut frames, mut next_minute, mut first_minute) = (0usize, 1u64, None);
    let mut refused = 0usize;
    let print_events = std::env::var_os("MEMORY_EVENTS").is_some();
    'play: for lap in 0u64.. {
        for (k, row) in imu.iter().enumerate() {
            let t_ns = row.stamp - first + lap * span_ns;
            if t_ns >= end_ns {
                break 'play;
            }
            if let Some(&f) = triggers.get(&k) {
                let stamp = dataset.frames[f].stamp - first + lap * span_ns;
                let frame = Frame::decoded(frames, stamp as i64, images[f].clone());
                // A frame refused is a frame a live program lost; the run goes on.
                if let Err(e) = tracker.push_frame(frame) {
                    refused += 1;
                    if refused <= 3 {
                        println!("memory: frame {frames} refused: {e}");
                    }
                }
                frames += 1;
            }
            tracker.push_imu(ImuSample {
                t_ns,
                gyro: row.gyro.into(),
                accel: row.accel.into(),
            })?;
            for event in tracker.poll() {
                if print_events
                    && !matches!(event, tracker::Event::Frame(_) | tracker::Event::Pose(_))
                {
                    println!("memory: {:.2} s: {event:?}", t_ns as f64 * 1e-9);
                }
            }
            if t_ns >= next_minute * 60_000_000_000 {
                let rss = status_mb("VmRSS:");
                first_minute.get_or_insert(rss);
                println!(
                    "| {next_minute} | {frames} | {rss:.1} | {:.0} |",
                    began.elapsed().as_secs_f64()
                );
                next_minute += 1;
            }
        }
    }
    // At the end of the sensor time, the tracker still running.
    let rss = status_mb("VmRSS:");
    let done = tracker.finish();
    done.result?;
    let at_one = first_minute.unwrap_or(f64::NAN);
    let tracker::Tally { tracked, judged } = done.tally;
    println!(
        "memory: VmRSS {at_one:.1} MB after one minute, {rss:.1} MB at the end ({:+.1} %); peak VmHWM {:.1} MB; {judged} frames judged, {tracked} tracked",
        100.0 * (rss / at_one - 1.0),
        status_mb("VmHWM:"),
    );
    Ok(())
}
