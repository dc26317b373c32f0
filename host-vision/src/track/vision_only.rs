//! Tracking without an IMU: the frames of a video, a camera, an image folder or a dataset's
//! `cam0`, pushed into the library's [`Tracker`], which drives the core's vision-only model by
//! `Tick`s (protocol 2.1; its steps are in [`tracker::tracker`]). This is the replay loop
//! around it: the frames read, the faults' noise frames put in, `--duration` and
//! `--max-frames`, Ctrl-C and the progress.
//!
//! Each frame is analysed before the next is read. A live camera (`--video /dev/video0`) is
//! paced by the camera through the same pipe; when the analysis is slower than the camera,
//! ffmpeg's pipe buffers the frames, so the tracker then runs late rather than dropping any.

use std::sync::atomic::{AtomicBool, Ordering};

use tracker::{Answers, Finished, Tracker, TrackerConfig, TrackerError};

use super::{FaultyLink, Progress, TrackError, TrackOptions};

use crate::camera::CameraPose;
use crate::dataset::Dataset;
use crate::frames::FrameSource;

/// Frame rate assumed when the input states none [Hz].
const DEFAULT_CAMERA_RATE_HZ: f64 = 30.0;

/// The dataset a run reads: a EuRoC folder, or, for a video or image folder, one built from
/// the camera given on the command line.
pub(super) fn open_dataset(options: &TrackOptions) -> Result<Dataset, TrackError> {
    match &options.frames {
        None => {
            let mut dataset = Dataset::open(&options.dataset)?;
            if let Some(camera) = options.camera {
                dataset.camera.camera = camera;
            }
            Ok(dataset)
        }
        Some(input) => {
            if !input.path().exists() {
                return Err(crate::frames::FrameError::Missing {
                    path: input.path().to_owned(),
                }
                .into());
            }
            let camera = options.camera.ok_or_else(|| {
                TrackError::Option(format!(
                    "{}: give the camera's intrinsics: --camera camera.json, --calib (Kalibr or EuRoC YAML) or --intrinsics fx,fy,cx,cy",
                    input.path().display()
                ))
            })?;
            Ok(Dataset::frames_only(input.path(), camera))
        }
    }
}

/// The start of a vision-only run: the given pose, or the ground truth's camera pose at the
/// first frame (a dataset whose IMU is withheld); `None`: the cold start finds it.
fn vision_start(options: &TrackOptions, dataset: &Dataset, first_stamp: u64) -> Option<CameraPose> {
    if options.start.cold {
        return None;
    }
    match (&options.start.pose, dataset.groundtruth_at(first_stamp)) {
        (Some(pose), _) => Some(*pose),
        (None, Some((p, q))) => {
            let (c_w, q_cw) = dataset.hand_eye.camera_pose(&p, &q);
            Some(CameraPose { q_cw, c_w })
        }
        (None, None) => None,
    }
}

/// Tracks the frames of `source` with the library's tracker, the core behind `link`. Returns
/// what the tracker leaves (its record, the link, and how it ended; `Ok(false)` when
/// interrupted), or the error that kept it from starting.
pub(super) fn track_frames(
    options: &TrackOptions,
    dataset: &Dataset,
    link: FaultyLink,
    model: &crate::model::Model,
    source: &mut FrameSource,
    interrupt: &AtomicBool,
    progress: Progress,
) -> Result<(Finished<FaultyLink>, Result<bool, TrackError>), TrackError> {
    // The first frame fixes the clock (and, with a ground truth, the start pose).
    let first = match source.next() {
        Some(Ok(f)) => f,
        Some(Err(e)) => return Err(e.into()),
        None => {
            return Err(TrackError::Option(format!(
                "{}: no frames",
                dataset.root.display()
            )));
        }
    };
    let (w, h) = first.image.dimensions();
    let camera = &dataset.camera.camera;
    if (w, h) != (camera.width, camera.height) {
        return Err(TrackError::Option(format!(
            "{}: the frames are {w}x{h} pixels, the camera's intrinsics are for {}x{}",
            dataset.root.display(),
            camera.width,
            camera.height
        )));
    }
    let rate = source
        .nominal_rate_hz()
        .or(dataset.camera.rate_hz)
        .filter(|r| r.is_finite() && *r > 0.0)
        .unwrap_or(DEFAULT_CAMERA_RATE_HZ);
    let config = TrackerConfig {
        start: vision_start(options, dataset, u64::try_from(first.t_ns).unwrap_or(0))
            .map_or(tracker::Start::Locate, tracker::Start::Camera),
        vision: options.vision,
        tuning: options.tuning,
        timeout: options.timeout,
        answers: if source.is_live() {
            Answers::WhenReady
        } else {
            Answers::AtNextFrame
        },
        keep_image_every: options.overlay_every,
        session_id: super::new_session_id(),
        ..TrackerConfig::new(*camera, rate, options.cache.clone())
    };
    let t0_ns = first.t_ns;
    let mut tracker = Tracker::new(config, model, link)?;
    let total = source.len_hint().unwrap_or(0);
    let mut frames = 0usize;
    let mut next = Some(Ok(first));
    let outcome = loop {
        let Some(frame) = next.take().or_else(|| source.next()) else {
            break Ok(true);
        };
        if interrupt.load(Ordering::Relaxed) {
            break Ok(false);
        }
        let mut frame = match frame {
            Ok(f) => f,
            Err(e) => break Err(e.into()),
        };
        let t_us = u64::try_from((frame.t_ns - t0_ns) / 1000).unwrap_or(0);
        let faults = &options.faults;
        if faults.blind_at(t_us as f64 * 1e-6) {
            frame.image = faults.noise_frame(w, h, frame.index);
        }
        if options.duration.is_some_and(|d| t_us as f64 > d * 1e6)
            || options.max_frames.is_some_and(|m| frames >= m)
        {
            break Ok(true);
        }
        match tracker.push_frame(frame.into()) {
            Ok(()) => frames += 1,
            // Refused and recorded: the next frame is tried.
            Err(TrackerError::TimeBackwards { .. } | TrackerError::ImageSize { .. }) => {}
            Err(e) => break Err(e.into()),
        }
        if frames.is_multiple_of(10) {
            let r = tracker.record();
            progress(frames, total, r.results.len(), r.log.mode());
        }
    };
    let finished = match outcome {
        Ok(false) => tracker.abandon(),
        _ => tracker.finish(),
    };
    let r = &finished.record;
    progress(frames, total.max(frames), r.results.len(), r.log.mode());
    Ok((finished, outcome))
}
