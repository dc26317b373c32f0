//! Tracking without an IMU: the frames of a video, a camera, an image folder or a dataset's
//! `cam0`, pushed into the library's [`Tracker`], which drives the core's vision-only model by
//! `Tick`s (protocol 2.1; its steps are in [`tracker::tracker`]). This is the replay loop
//! around it: the frames read, the faults' noise frames put in, `--duration` and
//! `--max-frames`, Ctrl-C and the progress.
//!
//! A replay analyses each frame before the next is read, the same every time. A live camera
//! (`--video /dev/video0`), or a recording played at its own rate (`--pacing real-time`), is
//! read on a capture thread that keeps only the newest frame: the tracker never runs late
//! behind a queue, and the frames it had no time for are counted as dropped.

use std::sync::atomic::{AtomicBool, Ordering};

use frames::live::{LiveFrames, Paced};
use tracker::record::Record;
use tracker::{Tracker, TrackerBuilder, TrackerError};
use vision::FrameImage;

use super::{FaultyLink, Progress, Ran, TrackError, TrackOptions};

use crate::camera::CameraPose;
use frames::euroc::Dataset;
use frames::{Frame, FrameSource};

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
                return Err(frames::FrameError::Missing {
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
/// what the run leaves (the record of the tracker's events, the link, and how it ended;
/// `Ok(false)` when interrupted), or the error that kept it from starting.
///
/// A replay takes every frame in order. A live run (a camera, or `--pacing real-time`, which
/// plays a recording at its own rate as a camera would) reads the source on a capture thread
/// that keeps only the newest frame ([`frames::live`]): the tracker takes it when it is
/// ready, and the frames it never saw are dropped, never queued.
pub(super) fn track_frames(
    options: &TrackOptions,
    dataset: &Dataset,
    link: FaultyLink,
    model: &crate::model::Model,
    mut source: FrameSource,
    interrupt: &AtomicBool,
    progress: Progress,
) -> Result<Ran, TrackError> {
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
    let live = options.live();
    let tracker = TrackerBuilder::new(*camera, model.clone())
        .frame_rate_hz(rate)
        .start(
            vision_start(options, dataset, u64::try_from(first.t_ns).unwrap_or(0))
                .map_or(tracker::Start::Locate, tracker::Start::Camera),
        )
        .live(live)
        .cache(options.cache.clone())
        .configure(super::command_settings(options))
        .build_with(link)?;
    let mut run = FrameLoop {
        options,
        tracker,
        t0_ns: first.t_ns,
        size: (w, h),
        total: source.len_hint().unwrap_or(0),
        frames: 0,
        progress,
        record: Record::default(),
    };
    let outcome = if live {
        run.live(first, source, interrupt)
    } else {
        run.replay(first, source, interrupt)
    };
    let FrameLoop {
        tracker,
        frames,
        total,
        progress,
        record,
        ..
    } = run;
    let finished = match outcome {
        Ok(false) => tracker.abandon(),
        _ => tracker.finish(),
    };
    let ran = Ran::of(finished, record, outcome);
    let r = &ran.record;
    progress(frames, total.max(frames), r.results.len(), r.log.mode());
    Ok(ran)
}

/// A run's frames pushed into its tracker.
struct FrameLoop<'a, 'p> {
    options: &'a TrackOptions,
    tracker: Tracker<FaultyLink>,
    /// The first frame's stamp [ns].
    t0_ns: i64,
    size: (u32, u32),
    /// Frames announced (0: unknown).
    total: usize,
    /// Frames pushed and taken.
    frames: usize,
    progress: Progress<'p>,
    /// The tracker's events so far.
    record: Record,
}

/// What to do after a frame.
enum Next {
    Go,
    /// The end of the run: `Ok(true)` at `--duration` or `--max-frames`.
    Stop(Result<bool, TrackError>),
}

impl FrameLoop<'_, '_> {
    /// Every frame in order, each analysed before the next is read.
    fn replay(
        &mut self,
        first: Frame,
        source: FrameSource,
        interrupt: &AtomicBool,
    ) -> Result<bool, TrackError> {
        for frame in std::iter::once(Ok(first)).chain(source) {
            if interrupt.load(Ordering::Relaxed) {
                return Ok(false);
            }
            match self.push(frame?.into(), self.frames) {
                Next::Go => {}
                Next::Stop(outcome) => return outcome,
            }
        }
        Ok(true)
    }

    /// The newest frame each time the tracker is ready, from a capture thread; a recording
    /// played at its own rate.
    fn live(
        &mut self,
        first: Frame,
        source: FrameSource,
        interrupt: &AtomicBool,
    ) -> Result<bool, TrackError> {
        let camera = source.is_live();
        let frames = std::iter::once(Ok(first))
            .chain(source)
            .map(|f| f.map(tracker::Frame::from));
        let mut live = if camera {
            LiveFrames::start(frames)
        } else {
            LiveFrames::start(Paced::new(frames))
        }
        .map_err(|e| TrackError::Option(format!("cannot start the capture thread: {e}")))?;
        while let Some(captured) = live.next_frame() {
            if interrupt.load(Ordering::Relaxed) {
                return Ok(false);
            }
            let frame = captured?.frame;
            let index = frame.index;
            match self.push(frame, index) {
                Next::Go => {}
                Next::Stop(outcome) => return outcome,
            }
        }
        Ok(true)
    }

    /// One frame into the tracker, with the faults' noise frames, `--duration` and
    /// `--max-frames` (`seen`: how far into the input it is), and the progress.
    fn push(&mut self, mut frame: tracker::Frame, seen: usize) -> Next {
        let o = self.options;
        let t_us = u64::try_from((frame.t_ns - self.t0_ns) / 1000).unwrap_or(0);
        if o.faults.blind_at(t_us as f64 * 1e-6) {
            let (w, h) = self.size;
            frame.image = FrameImage::Decoded(o.faults.noise_frame(w, h, frame.index));
        }
        if o.duration.is_some_and(|d| t_us as f64 > d * 1e6)
            || o.max_frames.is_some_and(|m| seen >= m)
        {
            return Next::Stop(Ok(true));
        }
        match self.tracker.push_frame(frame) {
            Ok(()) => self.frames += 1,
            // Refused and recorded: the next frame is tried.
            Err(TrackerError::TimeBackwards { .. } | TrackerError::ImageSize { .. }) => {}
            Err(e) => return Next::Stop(Err(e.into())),
        }
        for e in self.tracker.poll() {
            self.record.observe(&e);
        }
        if self.frames.is_multiple_of(10) {
            let r = &self.record;
            (self.progress)(self.frames, self.total, r.results.len(), r.log.mode());
        }
        Next::Go
    }
}
