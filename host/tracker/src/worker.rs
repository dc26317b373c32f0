//! The vision threads: each owns a renderer (made once, on its own thread) and answers
//! jobs in order: a frame's analysis at its predicted pose, the judgement of the pose
//! estimated with it, a cold-start attempt, or a tilt check. The tracker has two: one for the
//! frames, and one for the searches, so that an attempt never holds up the frames.

use std::path::PathBuf;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::time::{Duration, Instant};

use nalgebra::Vector3;
use vision::{Assessment, FrameJob, FrameResult, Vision, VisionOptions};

use crate::error::TrackerError;

/// Whether the model has a textured material, which registering its texture and searching for
/// it need.
pub use vision::is_textured;

/// The vision thread, with the channels to it. Stopped and joined on drop, so that no early
/// return leaves the renderer to be torn down by the process's exit.
pub struct VisionWorker {
    /// The shortest time an attempt takes ([`Self::set_search_floor`]).
    floor: Duration,
    jobs: Option<Sender<WorkerJob>>,
    results: Receiver<WorkerDone>,
    handle: Option<std::thread::JoinHandle<()>>,
}

/// What the vision thread is asked to do.
pub enum WorkerJob {
    /// Analyse a frame.
    Frame(FrameJob),
    /// Analyse a frame and judge it at its prediction ([`Vision::process_judged`]).
    FrameJudged(FrameJob),
    /// Judge the last analysed frame at the pose estimated with its update, over the
    /// correspondences the core applied.
    Assess(camera::CameraPose, Vec<bool>),
    /// Find the model in a raw frame with no pose given (the cold start), with the viewpoint
    /// database of this cache folder, answering no sooner than the duration given
    /// ([`VisionWorker::set_search_floor`]).
    Locate(image::GrayImage, PathBuf, Duration),
    /// Check the tilt of a tracked pose in its raw frame ([`locate::choice::check_tilt`]).
    CheckTilt(image::GrayImage, camera::CameraPose),
}

/// An attempt's answer, with the database's provenance on the attempt that loaded it.
pub type Located = (locate::Attempt, Option<locate::database::Provenance>);

/// What the vision thread answers, in the order of the jobs.
pub enum WorkerDone {
    /// A frame's analysis.
    Frame(Box<Result<FrameResult, TrackerError>>),
    /// A frame's judgement.
    Assess(Result<Assessment, TrackerError>),
    /// With the database's provenance, on the attempt that loaded or built it.
    Locate(
        Box<Result<locate::Attempt, TrackerError>>,
        Option<locate::database::Provenance>,
    ),
    /// The tilt check's evidence, and the other tilt where it is the pose.
    CheckTilt(Box<Result<locate::choice::TiltCheck, TrackerError>>),
}

impl VisionWorker {
    /// Starts the thread and waits until its renderer is set up.
    pub fn start(
        camera: camera::Camera,
        model: model::Model,
        options: VisionOptions,
    ) -> Result<(Self, Ready), TrackerError> {
        let (job_tx, job_rx) = channel::<WorkerJob>();
        let (res_tx, res_rx) = channel::<WorkerDone>();
        let (ready_tx, ready_rx) = channel::<Result<Ready, TrackerError>>();
        let handle = std::thread::Builder::new()
            .name("vision".into())
            .spawn(move || vision_worker(camera, model, options, job_rx, res_tx, ready_tx))
            .map_err(|e| {
                TrackerError::VisionThread(format!("cannot start the vision thread: {e}"))
            })?;
        let worker = VisionWorker {
            floor: Duration::ZERO,
            jobs: Some(job_tx),
            results: res_rx,
            handle: Some(handle),
        };
        let ready = ready_rx
            .recv()
            .map_err(|_| TrackerError::VisionThread("the vision thread stopped".into()))??;
        Ok((worker, ready))
    }

    /// Sends any job.
    pub fn send_job(&self, job: WorkerJob) -> Result<(), TrackerError> {
        self.jobs
            .as_ref()
            .and_then(|j| j.send(job).ok())
            .ok_or_else(|| TrackerError::VisionThread("the vision thread stopped".into()))
    }

    /// Sends a frame to analyse (its answer comes by [`Self::recv`] or [`Self::try_recv`]).
    pub fn send(&self, job: FrameJob) -> Result<(), TrackerError> {
        self.send_job(WorkerJob::Frame(job))
    }

    /// Sends a frame to analyse and judge at its prediction (answered as [`Self::send`]'s).
    pub fn send_judged(&self, job: FrameJob) -> Result<(), TrackerError> {
        self.send_job(WorkerJob::FrameJudged(job))
    }

    fn stopped() -> TrackerError {
        TrackerError::VisionThread("the vision thread stopped".into())
    }

    fn out_of_order() -> TrackerError {
        TrackerError::VisionThread("the vision thread answered out of order".into())
    }

    /// The analysis of the frame sent, waited for.
    pub fn recv(&self) -> Result<Result<FrameResult, TrackerError>, TrackerError> {
        match self.results.recv() {
            Ok(WorkerDone::Frame(r)) => Ok(*r),
            Ok(_) => Err(Self::out_of_order()),
            Err(_) => Err(Self::stopped()),
        }
    }

    /// The analysis of the frame sent, if it is ready.
    pub fn try_recv(&self) -> Option<Result<FrameResult, TrackerError>> {
        match self.results.try_recv().ok()? {
            WorkerDone::Frame(r) => Some(*r),
            _ => Some(Err(Self::out_of_order())),
        }
    }

    /// The next answer of any kind: waiting for it (`block`), or only if it is there.
    pub fn recv_any(&self, block: bool) -> Result<Option<WorkerDone>, TrackerError> {
        if block {
            self.results.recv().map(Some).map_err(|_| Self::stopped())
        } else {
            match self.results.try_recv() {
                Ok(d) => Ok(Some(d)),
                Err(std::sync::mpsc::TryRecvError::Empty) => Ok(None),
                Err(std::sync::mpsc::TryRecvError::Disconnected) => Err(Self::stopped()),
            }
        }
    }

    /// One cold-start attempt on the raw frame `image`, waited for (no frame may be in
    /// flight).
    pub fn locate(&self, image: image::GrayImage, cache: PathBuf) -> Result<Located, TrackerError> {
        self.send_locate(image, cache)?;
        self.locate_result()
    }

    /// Starts an attempt on `image` (its answer comes by [`Self::locate_result`] or
    /// [`Self::try_locate`]).
    pub fn send_locate(&self, image: image::GrayImage, cache: PathBuf) -> Result<(), TrackerError> {
        self.send_job(WorkerJob::Locate(image, cache, self.floor))
    }

    /// The answer of the attempt sent, waited for.
    pub fn locate_result(&self) -> Result<Located, TrackerError> {
        match self.recv_any(true)? {
            Some(WorkerDone::Locate(r, from)) => r.map(|a| (a, from)),
            Some(_) => Err(Self::out_of_order()),
            None => Err(Self::stopped()),
        }
    }

    /// The answer of the attempt sent, if it is ready.
    pub fn try_locate(&self) -> Result<Option<Located>, TrackerError> {
        match self.recv_any(false)? {
            Some(WorkerDone::Locate(r, from)) => r.map(|a| Some((a, from))),
            Some(_) => Err(Self::out_of_order()),
            None => Ok(None),
        }
    }

    /// Makes every attempt take at least `floor`: an answer found sooner is held back until
    /// then, as on a slower machine ([`crate::TrackerConfig::search_floor`]).
    pub fn set_search_floor(&mut self, floor: Duration) {
        self.floor = floor;
    }

    /// Starts the tilt check of the tracked `pose` in its raw frame `image` (its answer comes
    /// by [`Self::tilt_result`]).
    pub fn send_tilt_check(
        &self,
        image: image::GrayImage,
        pose: camera::CameraPose,
    ) -> Result<(), TrackerError> {
        self.send_job(WorkerJob::CheckTilt(image, pose))
    }

    /// The answer of the tilt check sent: waited for (`block`), or only if it is ready
    /// (`Ok(None)` when not).
    pub fn tilt_result(
        &self,
        block: bool,
    ) -> Result<Option<locate::choice::TiltCheck>, TrackerError> {
        match self.recv_any(block)? {
            Some(WorkerDone::CheckTilt(r)) => (*r).map(Some),
            Some(_) => Err(Self::out_of_order()),
            None if block => Err(Self::stopped()),
            None => Ok(None),
        }
    }

    /// Judges the last analysed frame at `pose` over the correspondences `applied` (no frame
    /// may be in flight).
    pub fn assess(
        &self,
        pose: camera::CameraPose,
        applied: Vec<bool>,
    ) -> Result<Assessment, TrackerError> {
        self.send_job(WorkerJob::Assess(pose, applied))?;
        match self.results.recv() {
            Ok(WorkerDone::Assess(r)) => r,
            Ok(_) => Err(Self::out_of_order()),
            Err(_) => Err(Self::stopped()),
        }
    }

    /// Ends the thread (it returns once its job channel is closed) and waits for it.
    pub fn stop(&mut self) {
        self.jobs = None;
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

impl Drop for VisionWorker {
    fn drop(&mut self) {
        self.stop();
    }
}

fn vision_worker(
    camera: camera::Camera,
    model: model::Model,
    options: VisionOptions,
    jobs: Receiver<WorkerJob>,
    results: Sender<WorkerDone>,
    ready: Sender<Result<Ready, TrackerError>>,
) {
    let setup = || -> Result<(Vision, Ready), TrackerError> {
        if options.modality.texture() && !is_textured(&model) {
            return Err(TrackerError::Untextured);
        }
        let vision = Vision::new(camera, &model, options)?;
        let ready = Ready {
            adapter: vision.adapter_summary(),
            axes: model_axes(&model),
        };
        Ok((vision, ready))
    };
    let mut vision = match setup() {
        Ok((v, r)) => {
            let _ = ready.send(Ok(r));
            v
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    // The cold start's database, loaded (or built) on the first attempt.
    let mut locator: Option<locate::Locator> = None;
    let mut provenance = None;
    // Ends when the session drops its sender.
    while let Ok(job) = jobs.recv() {
        let done = match job {
            WorkerJob::Frame(job) => {
                WorkerDone::Frame(Box::new(vision.process(job).map_err(TrackerError::from)))
            }
            WorkerJob::FrameJudged(job) => WorkerDone::Frame(Box::new(
                vision.process_judged(job).map_err(TrackerError::from),
            )),
            WorkerJob::Assess(pose, applied) => {
                WorkerDone::Assess(vision.assess(&pose, &applied).map_err(TrackerError::from))
            }
            WorkerJob::Locate(image, cache, floor) => {
                let began = Instant::now();
                let attempt = (|| {
                    if locator.is_none() {
                        let (db, from) = locate::database::Database::load_or_build(
                            &model,
                            &locate::database::DatabaseConfig::default(),
                            &cache,
                            &mut |_, _| {},
                        )?;
                        locator = Some(locate::Locator::new(&db, Default::default()));
                        provenance = Some(from);
                    }
                    match &locator {
                        Some(l) => Ok(l.attempt(&mut vision, &image, false)?.0),
                        None => Err(TrackerError::VisionThread("no cold-start database".into())),
                    }
                })();
                if let Some(rest) = floor.checked_sub(began.elapsed()) {
                    std::thread::sleep(rest);
                }
                WorkerDone::Locate(Box::new(attempt), provenance.take())
            }
            WorkerJob::CheckTilt(image, pose) => WorkerDone::CheckTilt(Box::new(
                locate::choice::check_tilt(
                    &mut vision,
                    &image,
                    &pose,
                    &locate::LocateConfig::default().rule,
                )
                .map_err(TrackerError::from),
            )),
        };
        if results.send(done).is_err() {
            return;
        }
    }
}

/// What the vision worker reports once set up.
pub struct Ready {
    /// The renderer's adapter, for reports.
    pub adapter: String,
    /// Where overlays draw the model's axes, and their length [m].
    pub axes: (Vector3<f64>, f64),
}

/// Where the overlays draw the model's axes: the centre of its bounding box, a quarter of its
/// largest extent long.
pub fn model_axes(model: &model::Model) -> (Vector3<f64>, f64) {
    let Some((lo, hi)) = model.bounds() else {
        return (Vector3::zeros(), 0.1);
    };
    let (lo, hi) = (Vector3::from(lo), Vector3::from(hi));
    ((lo + hi) * 0.5, ((hi - lo).max() * 0.25).max(0.02))
}
