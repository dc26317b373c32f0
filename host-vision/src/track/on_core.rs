//! `track --imu-on-core`: the dataset replayed with the core sampling its own IMU
//! (protocol/PROTOCOL.md §7), as on sensor hardware. The in-process board is fitted with a
//! simulated ICM-42688-P (`icm42688::SimIcm42688`); each of the dataset's IMU readings goes
//! into the part at its time, the board's sample path (`sample_path::SamplePath`) reads,
//! stamps and scales it into the core, and the core fires the camera every k-th sample. The
//! dataset's frame of each trigger is pushed after it, and the library pairs it with the
//! core's `Trigger`; the host sends no `Imu`.
//!
//! The core's samples, as it reported them, are written as `core_imu.csv` (EuRoC's `imu0`
//! layout): a host-driven replay of them tracks the same trajectory, and a calibration
//! (Kalibr) takes them as they are.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use firmware_sim::sim::scenario::euroc::IMU_HEADER;
use firmware_sim::sim::sensor_board::odr_for;
use icm42688::{Odr, Settings};
use tracker::{ImuOnCore, Tracker};
use vision::FrameImage;

use super::{FaultyLink, Pacing, Progress, Ran, TrackError, TrackOptions};
use core_link::LinkSpec;
use frames::euroc::Dataset;

/// The dataset's frames as the core's trigger would take them: every `every`-th IMU sample
/// from `first`. Returns `(first, every)`.
fn trigger_plan(dataset: &Dataset) -> Result<(usize, u16), TrackError> {
    let triggers = dataset.triggers();
    let bad = |m: String| Err(TrackError::Option(format!("--imu-on-core: {m}")));
    if triggers.len() < 2 || triggers.len() != dataset.frames.len() {
        return bad(format!(
            "{} of the dataset's {} frames fall on an IMU sample: the core's trigger takes a frame at a sample",
            triggers.len(),
            dataset.frames.len()
        ));
    }
    let (_, first) = triggers[0];
    let every = triggers[1].1 - first;
    for (i, w) in triggers.windows(2).enumerate() {
        if w[1].1 - w[0].1 != every {
            return bad(format!(
                "frame {} is {} IMU samples after the one before, not {every}: the core triggers the camera every k-th sample",
                i + 1,
                w[1].1 - w[0].1
            ));
        }
    }
    let every = u16::try_from(every)
        .ok()
        .filter(|&e| e <= protocol::validate::MAX_TRIGGER_EVERY)
        .ok_or(TrackError::Option(format!(
            "--imu-on-core: a frame every {every} IMU samples is more than the core's trigger counts ({})",
            protocol::validate::MAX_TRIGGER_EVERY
        )))?;
    Ok((first, every))
}

/// The simulated part's settings for the dataset's IMU rate.
fn part_settings(dataset: &Dataset) -> Result<Settings, TrackError> {
    let odr = odr_for(dataset.imu_rate_hz).ok_or_else(|| {
        let rates: Vec<String> = Odr::ALL.iter().map(|o| o.hz().to_string()).collect();
        TrackError::Option(format!(
            "--imu-on-core: the ICM-42688-P has no output data rate of {} Hz (it has {} Hz)",
            dataset.imu_rate_hz,
            rates.join(", ")
        ))
    })?;
    Ok(Settings::new(odr))
}

/// What `--imu-on-core` cannot be combined with, named.
fn check_options(options: &TrackOptions) -> Result<(), TrackError> {
    let bad = |m: &str| Err(TrackError::Option(format!("--imu-on-core: {m}")));
    if !matches!(options.link, LinkSpec::InProcess(_)) {
        return bad(
            "the dataset's IMU is replayed through a simulated ICM-42688-P on the in-process board: use --link inproc (a real board samples its own IMU, with no dataset to replay)",
        );
    }
    if options.pacing != Pacing::LockStep {
        return bad("the replay through the simulated part runs lock-step only");
    }
    if options.faults.reset_core_at.is_some() || options.faults.cut_link_at.is_some() {
        return bad(
            "outages (--reset-core-at, --cut-link-at) are not supported with the core sampling its own IMU yet",
        );
    }
    Ok(())
}

/// Tracks the dataset with the core sampling the simulated part.
pub(super) fn track(
    options: &TrackOptions,
    dataset: &Dataset,
    mut link: FaultyLink,
    model: &crate::model::Model,
    end: usize,
    interrupt: &AtomicBool,
    progress: Progress,
) -> Result<Ran, TrackError> {
    check_options(options)?;
    let (first, every) = trigger_plan(dataset)?;
    link.link_mut().fit_simulated_imu(part_settings(dataset)?)?;
    let mut tracker = super::inertial_tracker(options, dataset, model)?
        .imu_on_core(ImuOnCore::new(every, dataset.imu_rate_hz))
        .build_with(link)?;
    let mut record = super::Record::default();
    let stamp0 = dataset.imu[first].stamp;
    let cam = &dataset.camera.camera;
    let mut next_frame = 0;
    let mut outcome = Ok(true);
    for k in first..end {
        if interrupt.load(Ordering::Relaxed) {
            outcome = Ok(false);
            break;
        }
        let row = &dataset.imu[k];
        // The MCU's clock counts from the first sample, as the host-driven replay's does.
        let t_us = (row.stamp - stamp0) / 1000;
        let step = tracker
            .core_mut()
            .link_mut()
            .simulated_imu_sample(t_us, row.gyro.into(), row.accel.into())
            .map_err(TrackError::from)
            .and_then(|triggered| match triggered {
                true => {
                    let expected = first + next_frame * usize::from(every);
                    push_triggered(
                        options,
                        dataset,
                        &mut tracker,
                        &mut next_frame,
                        (k, expected),
                        cam,
                    )
                }
                false => tracker.pump().map_err(TrackError::from),
            });
        if let Err(e) = step {
            outcome = Err(e);
            break;
        }
        super::sample_progress(&mut tracker, &mut record, k, end, progress);
    }
    Ok(super::wind_up(tracker, record, outcome, end, progress))
}

/// The core fired the camera at sample `k`: the dataset's next frame, which the trigger plan
/// put at sample `expected`, goes to the tracker.
fn push_triggered(
    options: &TrackOptions,
    dataset: &Dataset,
    tracker: &mut Tracker<FaultyLink>,
    next_frame: &mut usize,
    (k, expected): (usize, usize),
    cam: &crate::camera::Camera,
) -> Result<(), TrackError> {
    let f = *next_frame;
    let Some(frame) = dataset.frames.get(f) else {
        // The dataset's frames are over: the trigger is the camera's only.
        return tracker.pump().map_err(TrackError::from);
    };
    *next_frame += 1;
    let stamp0 = dataset.imu[0].stamp;
    let t = |stamp: u64| (stamp - stamp0) as f64 * 1e-9;
    if k != expected {
        return Err(TrackError::Option(format!(
            "--imu-on-core: the core triggered frame {f} at the sample of t = {:.4} s, and the dataset's frame {f} is at t = {:.4} s",
            t(dataset.imu[k].stamp),
            t(frame.stamp)
        )));
    }
    let t_us = (frame.stamp - stamp0) / 1000;
    let image = if options.faults.blind_at(super::output::seconds(t_us)) {
        FrameImage::Decoded(options.faults.noise_frame(cam.width, cam.height, f))
    } else {
        FrameImage::File(frame.path.clone())
    };
    tracker
        .push_frame(tracker::Frame {
            index: f,
            t_ns: frame.stamp as i64,
            image,
            captured: None,
        })
        .map_err(TrackError::from)
}

/// Writes the samples the core took, as it reported them, in EuRoC's `imu0` layout, on the
/// run's clock (the frames'): `core_imu.csv`.
pub(super) fn write_core_imu(
    out: &Path,
    record: &tracker::record::Record,
) -> Result<PathBuf, TrackError> {
    let path = out.join("core_imu.csv");
    let stamp0 = record.clock.first().copied().unwrap_or(0);
    let first_us = record.log.raw_imu.first().map_or(0, |s| s.t_us);
    let mut text = String::with_capacity(record.log.raw_imu.len() * 96);
    text.push_str(IMU_HEADER);
    text.push('\n');
    for s in &record.log.raw_imu {
        let stamp = stamp0 + (s.t_us - first_us) * 1000;
        let [wx, wy, wz] = s.gyro;
        let [ax, ay, az] = s.accel;
        text.push_str(&format!("{stamp},{wx},{wy},{wz},{ax},{ay},{az}\n"));
    }
    std::fs::File::create(&path)
        .and_then(|mut f| f.write_all(text.as_bytes()))
        .map_err(|source| TrackError::Output {
            path: path.clone(),
            source,
        })?;
    Ok(path)
}
