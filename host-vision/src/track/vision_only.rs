//! Tracking without an IMU: the frames of a video, a camera, an image folder or a dataset's
//! `cam0` drive the core's vision-only model by `Tick`s (protocol 2.1).
//!
//! Per frame, in lock-step:
//! 1. `Tick { t, trigger }` at the frame's time stamp: the core answers with the prediction;
//! 2. the vision worker analyses the frame at the prediction, and its correspondences go to
//!    the core (which applies them at once: no later tick exists yet);
//! 3. `Tick { t + 1 µs }`: the core's `State` then holds the pose estimated with the frame;
//! 4. the worker judges that pose ([`super::assess`]): the registered features' reprojection
//!    rms, and the model rendered there against the live image.
//!
//! Each frame is analysed before the next is read. A live camera (`--video /dev/video0`) is
//! paced by the camera through the same pipe; when the analysis is slower than the camera,
//! ffmpeg's pipe buffers the frames, so the tracker then runs late rather than dropping any.

use std::sync::atomic::{AtomicBool, Ordering};

use protocol::{HostToCore, Init, InitAttitude, Tick};

use super::config::vision_config;
use super::{
    FaultyLink, FrameImage, FrameJob, Pending, Progress, Search, Session, Start, TrackError, TrackOptions,
    VisionWorker,
};
use image::GrayImage;

use crate::camera::CameraPose;
use crate::dataset::Dataset;
use crate::frames::{Frame, FrameSource};

/// Longest interval between two ticks [µs]: frames further apart (a stalled camera, dropped
/// frames) are bridged by ticks without a trigger, as the core refuses clock gaps of a
/// second.
const MAX_TICK_GAP_US: u64 = 500_000;

/// Frames not tracked for this long [µs] (or a divergence) mean the model is lost: the cold
/// start searches for it again (a hand hides an object for longer than half a second only when
/// it means to).
const LOST_AFTER_US: u64 = 500_000;

/// While lost, one search every this many frames: an attempt costs several frame periods, and
/// the frames between keep the loop going.
const SEARCH_EVERY: usize = 5;

/// While tracked, one tilt check every this many frames at most (docs/notes/issue15-cold-start.md
/// §5.2): it runs on the search thread, one at a time, and costs about as much as an attempt.
const TILT_CHECK_EVERY: usize = 5;

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

impl Session<'_> {
    /// The start of a vision-only run: the given pose, or the ground truth's camera pose at the
    /// first frame (a dataset whose IMU is withheld); `None`: the cold start finds it.
    fn vision_start(&self, first_stamp: u64) -> Option<CameraPose> {
        if self.options.start.cold {
            return None;
        }
        match (
            &self.options.start.pose,
            self.dataset.groundtruth_at(first_stamp),
        ) {
            (Some(pose), _) => Some(*pose),
            (None, Some((p, q))) => {
                let (c_w, q_cw) = self.dataset.hand_eye.camera_pose(&p, &q);
                Some(CameraPose { q_cw, c_w })
            }
            (None, None) => None,
        }
    }

    /// The core's `Init` for the camera at `pose`.
    fn vision_init(&self, pose: &CameraPose) -> Init {
        let (s_w, q_sw) = Start::imu_pose_of_camera(pose, &self.record.core_hand_eye);
        let q = q_sw.quaternion();
        Init {
            position: [s_w.x as f32, s_w.y as f32, s_w.z as f32],
            attitude: InitAttitude::Full([q.w as f32, q.i as f32, q.j as f32, q.k as f32]),
        }
    }

    /// Sends one tick at `t_us` after the first frame (stamp `stamp0` [ns]) and records its
    /// stamp.
    fn tick(
        &mut self,
        link: &mut FaultyLink,
        stamp0: u64,
        t_us: u64,
        trigger: bool,
    ) -> Result<(), TrackError> {
        link.send(&HostToCore::Tick(Tick { t_us, trigger }))?;
        self.record.clock.push(stamp0 + t_us * 1000);
        Ok(())
    }

    /// Runs a vision-only session over `source`; `Ok(false)` when interrupted.
    pub(super) fn drive_vision(
        &mut self,
        link: &mut FaultyLink,
        worker: &VisionWorker,
        search: Option<&VisionWorker>,
        source: &mut FrameSource,
        interrupt: &AtomicBool,
        progress: Progress,
    ) -> Result<bool, TrackError> {
        // Correspondences go out before the next tick: no latency to check against the core's
        // buffers.
        self.handshake(link)?;
        let total = source.len_hint().unwrap_or(0);
        let rate = source
            .nominal_rate_hz()
            .or(self.dataset.camera.rate_hz)
            .filter(|r| r.is_finite() && *r > 0.0)
            .unwrap_or(DEFAULT_CAMERA_RATE_HZ);
        let config = vision_config(rate, &self.options.tuning, self.record.session_id);
        // The first frame fixes the clock (and, with a ground truth, the start pose).
        let Some(first) = source.next() else {
            return Err(TrackError::Option(format!(
                "{}: no frames",
                self.dataset.root.display()
            )));
        };
        let first = first?;
        let (w, h) = first.image.dimensions();
        let camera = &self.dataset.camera.camera;
        if (w, h) != (camera.width, camera.height) {
            return Err(TrackError::Option(format!(
                "{}: the frames are {w}x{h} pixels, the camera's intrinsics are for {}x{}",
                self.dataset.root.display(),
                camera.width,
                camera.height
            )));
        }
        let t0_ns = first.t_ns;
        let first_stamp = u64::try_from(t0_ns).unwrap_or(0);
        self.send_confirmed(
            link,
            &HostToCore::Configure(config),
            protocol::StatusReason::Configured,
        )?;
        // Without a start pose the core is initialised once the cold start found the model.
        let start = self.vision_start(first_stamp);
        let mut started = start.is_some();
        if let Some(pose) = &start {
            let init = HostToCore::Init(self.vision_init(pose));
            self.send_confirmed(link, &init, protocol::StatusReason::HostRequest)?;
        }
        if let Some(e) = self.record.log.errors.first() {
            return Err(TrackError::Core(format!(
                "refused the configuration: {}",
                e.code
            )));
        }

        let mut next = Some(Ok(first));
        let mut frames = 0usize;
        let mut last_us: Option<u64> = None;
        // Since when the frames are not tracked, whether the core diverged since, and its
        // statuses already looked at.
        let mut untracked_since: Option<u64> = None;
        let mut diverged = false;
        let mut statuses_seen = self.record.log.statuses.len();
        let mut since_search = SEARCH_EVERY;
        // The recovery attempt with the search thread: its frame's index, time [µs], and
        // since when the model was lost [µs].
        let mut in_search: Option<(usize, u64, u64)> = None;
        let mut since_check = 0usize;
        let live = source.is_live();
        let search = search.ok_or_else(|| TrackError::VisionThread("no search thread".into()))?;
        let rule = super::TrackedRule::default();
        while let Some(frame) = next.take().or_else(|| source.next()) {
            if interrupt.load(Ordering::Relaxed) {
                self.barrier(link)?;
                return Ok(false);
            }
            let mut frame: Frame = frame?;
            let t_us = u64::try_from((frame.t_ns - t0_ns) / 1000).unwrap_or(0);
            let faults = &self.options.faults;
            if faults.blind_at(t_us as f64 * 1e-6) {
                frame.image = faults.noise_frame(w, h, frame.index);
            }
            if self.options.duration.is_some_and(|d| t_us as f64 > d * 1e6)
                || self.options.max_frames.is_some_and(|m| frames >= m)
            {
                break;
            }
            if last_us.is_some_and(|l| t_us <= l + 1) {
                self.record.frame_errors.push((
                    self.record.results.len(),
                    format!(
                        "frame {}: time stamp {} µs is within 1 µs of the previous frame's: skipped",
                        frame.index, t_us
                    ),
                ));
                continue;
            }
            if !started {
                // The cold start: one attempt per frame until a pose is verified; the frame
                // it was found in is then tracked from it.
                let (a, from) = search.locate(frame.image.clone(), self.options.cache.clone())?;
                self.record.keep_provenance(from);
                self.record.searches.push(Search::new(frame.index, t_us, a));
                let Some(pose) = a.pose else {
                    frames += 1;
                    if frames.is_multiple_of(10) {
                        progress(frames, total, self.record.results.len(), self.record.log.mode());
                    }
                    continue;
                };
                link.send(&HostToCore::Init(self.vision_init(&pose)))?;
                started = true;
            }
            // Recovery: lost after a divergence or half a second untracked; then a search
            // every few frames until a pose is verified, which re-initialises the core.
            if self.record.log.statuses[statuses_seen.min(self.record.log.statuses.len())..]
                .iter()
                .any(|st| st.mode == protocol::Mode::Diverged)
            {
                diverged = true;
                untracked_since.get_or_insert(t_us);
            }
            statuses_seen = self.record.log.statuses.len();
            // The attempt sent at an earlier frame: a file's frames wait for it at the next
            // frame (a replay is deterministic); a live camera's take it when it is ready.
            if let Some((index, at_us, since)) = in_search {
                let done = if live {
                    search.try_locate()?
                } else {
                    Some(search.locate_result()?)
                };
                if let Some((a, from)) = done {
                    in_search = None;
                    self.record.keep_provenance(from);
                    self.record.record_recovery(since as f64 * 1e-6, Search::new(index, at_us, a));
                    if let Some(pose) = a.pose {
                        link.send(&HostToCore::Init(self.vision_init(&pose)))?;
                        self.record.tilt.restart();
                        untracked_since = None;
                        diverged = false;
                    }
                }
            }
            // The tilt check sent at an earlier frame, taken like a search's answer: where it
            // found tracking on the other tilt of a face and the tracked tilt is settled, the
            // core is re-initialised there (`track/tilt.rs`).
            if self.record.tilt.in_flight()
                && let Some(check) = search.tilt_result(!live)?
                && let Some(pose) = self.record.tilt.answer(&check, t_us as f64 * 1e-6)
            {
                link.send(&HostToCore::Init(self.vision_init(&pose)))?;
            }
            let lost =
                diverged || untracked_since.is_some_and(|since| t_us >= since + LOST_AFTER_US);
            if !lost {
                self.record.end_recovery(t_us);
            } else if since_search >= SEARCH_EVERY && in_search.is_none() && !self.record.tilt.in_flight()
            {
                since_search = 0;
                search.send_locate(frame.image.clone(), self.options.cache.clone())?;
                in_search = Some((frame.index, t_us, untracked_since.unwrap_or(t_us)));
            } else {
                since_search += 1;
            }
            if let Some(mut at) = last_us {
                while t_us - at > MAX_TICK_GAP_US {
                    at += MAX_TICK_GAP_US;
                    self.tick(link, first_stamp, at, false)?;
                }
            }
            self.tick(link, first_stamp, t_us, true)?;
            last_us = Some(t_us);
            self.barrier(link)?;
            frames += 1;
            let mut tracked = false;
            let mut checked: Option<(GrayImage, CameraPose, u32)> = None;
            let check_due = since_check >= TILT_CHECK_EVERY
                && !self.record.tilt.in_flight()
                && in_search.is_none()
                && untracked_since.is_none();
            let check_image = check_due.then(|| frame.image.clone());
            if let Some(p) = self.record.log.predictions.get(&t_us).copied() {
                let every = self.options.overlay_every;
                let omega_c = self
                    .record
                    .log
                    .states
                    .last()
                    .filter(|s| s.t_us == t_us)
                    .map(|s| nalgebra::Vector3::from(s.omega_s.map(f64::from)));
                worker.send(FrameJob {
                    index: frame.index,
                    stamp: first_stamp + t_us * 1000,
                    image: FrameImage::Decoded(frame.image),
                    prediction: p,
                    keep_image: every > 0 && frame.index.is_multiple_of(every),
                    omega_c,
                })?;
                let result = worker.recv()?;
                let analysed = result.is_ok();
                self.deliver(
                    link,
                    Pending {
                        frame_id: p.frame_id,
                        trigger_us: t_us,
                        due: 0,
                    },
                    result,
                )?;
                // The pose estimated with this frame, just after it.
                self.tick(link, first_stamp, t_us + 1, false)?;
                last_us = Some(t_us + 1);
                self.barrier(link)?;
                let updated = self.record.log.states.last().filter(|s| s.t_us == t_us + 1);
                if let (true, Some(s)) = (analysed, updated) {
                    let (c_w, q_wc) = super::camera_of_state(s, &self.record.core_hand_eye);
                    let pose = CameraPose {
                        q_cw: q_wc.inverse(),
                        c_w,
                    };
                    // Which correspondences the core applied: its reports' residuals, part
                    // by part in the order sent, within the gate.
                    let gate = f64::from(config.gate);
                    let mut reports = self
                        .record
                        .log
                        .updates
                        .get(&p.frame_id)
                        .cloned()
                        .unwrap_or_default();
                    reports.sort_by_key(|r| r.part);
                    let applied: Vec<bool> = reports
                        .iter()
                        .flat_map(|r| r.residuals.iter())
                        .map(|&s_i| f64::from(s_i) <= gate)
                        .collect();
                    let a = worker.assess(pose, applied)?;
                    self.record.assessments.insert(p.frame_id, a);
                    tracked = rule.holds(&a);
                    self.record.tilt.judged(p.frame_id);
                    if tracked && let Some(image) = check_image {
                        checked = Some((image, pose, p.frame_id));
                    }
                }
            }
            match checked {
                Some((image, pose, frame_id)) => {
                    search.send_tilt_check(image, pose)?;
                    self.record.tilt.sent(frame.index, frame_id, pose);
                    since_check = 0;
                }
                None => since_check += 1,
            }
            if tracked {
                untracked_since = None;
                diverged = false;
            } else {
                untracked_since.get_or_insert(t_us);
            }
            if frames.is_multiple_of(10) {
                progress(frames, total, self.record.results.len(), self.record.log.mode());
            }
        }
        // A check still in flight confirms nothing: a flip not yet confirmed never held.
        if self.record.tilt.in_flight() {
            search.tilt_result(true)?;
        }
        self.record.tilt.restart();
        if let Some((index, at_us, since)) = in_search {
            let (a, from) = search.locate_result()?;
            self.record.keep_provenance(from);
            self.record.record_recovery(since as f64 * 1e-6, Search::new(index, at_us, a));
        }
        self.barrier(link)?;
        progress(
            frames,
            total.max(frames),
            self.record.results.len(),
            self.record.log.mode(),
        );
        Ok(true)
    }
}
