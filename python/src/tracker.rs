//! `Tracker`: the library's push-driven tracker. Frames (numpy) and IMU samples in; per-frame
//! reports, the latest pose and the state out. `Imu` describes the IMU of a run with one;
//! `FrameReport` is what one frame gave.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::str::FromStr;
use std::sync::Mutex;

use camera::start_pose::check_rigid;
use core_link::{CoreLink, LinkSpec};
use protocol::ModelKind;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use tracker::{Event, HandEye, ImuNoiseDensities, Rig, Start, TrackerBuilder};

use crate::camera::Camera;
use crate::error::{TrackerError, of_tracker, value_error};
use crate::image::{Channels, gray_of};
use crate::matrix::matrix4_of;
use crate::model::Model;
use crate::pose::{Pose, start_pose_of};

/// The IMU of a run with one: its rate, the camera's mount on it, the filter's model and,
/// where known, its noise.
#[pyclass(module = "vitracker", frozen)]
#[derive(Debug, Clone)]
pub struct Imu {
    rate_hz: f64,
    t_bs: Option<nalgebra::Matrix4<f64>>,
    filter: ModelKind,
    noise: Option<ImuNoiseDensities>,
}

/// The filter's model named as `track --filter` names it.
fn filter_of(name: &str) -> PyResult<ModelKind> {
    match name {
        "acc" => Ok(ModelKind::Acc),
        "gravity" => Ok(ModelKind::Gravity),
        "gyro" => Ok(ModelKind::Gyro),
        _ => Err(value_error(format!(
            "filter must be \"acc\", \"gravity\" or \"gyro\" (the paper's inertial models), got {name:?}"
        ))),
    }
}

#[pymethods]
impl Imu {
    /// An IMU sampled at `rate_hz`; `t_bs` is the camera's pose in its frame (4×4, EuRoC's
    /// `T_BS`; None: the camera's own, from its calibration file). The four noise densities
    /// (EuRoC `imu0/sensor.yaml`) go together; without them EuRoC's ADIS16448's are used.
    #[new]
    #[pyo3(signature = (rate_hz, t_bs = None, filter = "acc", gyroscope_noise_density = None, gyroscope_random_walk = None, accelerometer_noise_density = None, accelerometer_random_walk = None))]
    fn new(
        rate_hz: f64,
        t_bs: Option<&Bound<'_, PyAny>>,
        filter: &str,
        gyroscope_noise_density: Option<f64>,
        gyroscope_random_walk: Option<f64>,
        accelerometer_noise_density: Option<f64>,
        accelerometer_random_walk: Option<f64>,
    ) -> PyResult<Self> {
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Err(value_error(format!(
                "rate_hz must be a positive number of samples per second, got {rate_hz}"
            )));
        }
        let t_bs = t_bs.map(|t| matrix4_of(t, "t_bs")).transpose()?;
        let noise = match (
            gyroscope_noise_density,
            gyroscope_random_walk,
            accelerometer_noise_density,
            accelerometer_random_walk,
        ) {
            (None, None, None, None) => None,
            (Some(gn), Some(gw), Some(an), Some(aw)) => {
                if ![gn, gw, an, aw].iter().all(|v| v.is_finite() && *v > 0.0) {
                    return Err(value_error(format!(
                        "the IMU's noise densities must be positive numbers, got {gn}, {gw}, {an}, {aw}"
                    )));
                }
                Some(ImuNoiseDensities {
                    gyroscope_noise_density: gn,
                    gyroscope_random_walk: gw,
                    accelerometer_noise_density: an,
                    accelerometer_random_walk: aw,
                })
            }
            _ => {
                return Err(value_error(
                    "give the IMU's four noise densities together, or none",
                ));
            }
        };
        Ok(Imu {
            rate_hz,
            t_bs,
            filter: filter_of(filter)?,
            noise,
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "Imu({} Hz, filter={:?}, noise={})",
            self.rate_hz,
            self.filter,
            if self.noise.is_some() {
                "given"
            } else {
                "data sheet"
            }
        )
    }
}

/// What one frame gave.
#[pyclass(module = "vitracker", frozen, get_all)]
#[derive(Debug, Clone)]
pub struct FrameReport {
    /// The frame's index (from 0, in the order pushed, unless given).
    index: usize,
    /// Its time [s from the tracker's first frame or sample].
    t: f64,
    /// The pose its verdict is on (the core's pose at the frame's time), or None.
    pose: Option<Pose>,
    /// Whether it counts as tracked; None where it was not analysed.
    tracked: Option<bool>,
    /// Correspondences sent to the core (2D/3D and contour).
    correspondences: usize,
    /// Tracked with this direction weakly pinned ("depth", "sideways", "up-down", "tilt",
    /// "pan", "roll about the view"; docs/VISION.md eq. T7), or None.
    weak: Option<&'static str>,
    /// Why the frame could not be used, where it could not.
    skipped: Option<String>,
}

#[pymethods]
impl FrameReport {
    fn __repr__(&self) -> String {
        match &self.skipped {
            Some(why) => format!("FrameReport(index={}, skipped={why:?})", self.index),
            None => format!(
                "FrameReport(index={}, t={:.6}, tracked={}, weak={}, correspondences={}, pose={})",
                self.index,
                self.t,
                match self.tracked {
                    Some(true) => "True",
                    Some(false) => "False",
                    None => "None",
                },
                self.weak.map_or("None".into(), |w| format!("'{w}'")),
                self.correspondences,
                self.pose
                    .as_ref()
                    .map_or("None".into(), |p| format!("{:?}", p.camera.c_w.as_slice()))
            ),
        }
    }
}

/// The tracker (see the stub for the Python user's account).
#[pyclass(module = "vitracker")]
pub struct Tracker {
    /// None once finished. In a mutex only so that Python may hand the tracker between its
    /// threads: every method borrows it mutably, so the lock is never taken.
    inner: Mutex<Option<tracker::Tracker<CoreLink>>>,
    /// The index the next frame gets by default.
    next_index: usize,
    /// Frame reports polled from the tracker and not yet returned by `poll`.
    reports: Vec<FrameReport>,
    /// The core's poses polled from the tracker and not yet returned by `poll_poses`: the
    /// newest [`MAX_POSES`].
    poses: VecDeque<Pose>,
}

/// The most poses kept for `poll_poses` (20 s of a 200 Hz IMU): a program that never asks
/// for them does not grow without bound.
const MAX_POSES: usize = 4096;

/// Seconds to nanoseconds, for a time pushed (`what` names it in errors).
fn nanos(t: f64, what: &str) -> PyResult<i64> {
    let ns = (t * 1e9).round();
    if !(ns.is_finite() && ns.abs() < 9.0e18) {
        return Err(value_error(format!(
            "{what}: time {t} s is not a finite number of seconds"
        )));
    }
    Ok(ns as i64)
}

/// Three finite numbers (`what` names them in errors).
fn vector3(value: &Bound<'_, PyAny>, what: &str) -> PyResult<[f64; 3]> {
    let v: Vec<f64> = value
        .call_method0("tolist")
        .unwrap_or_else(|_| value.clone())
        .extract()
        .map_err(|_| value_error(format!("{what}: expected 3 numbers")))?;
    let v: [f64; 3] = v.try_into().map_err(|v: Vec<f64>| {
        value_error(format!("{what}: expected 3 numbers, got {}", v.len()))
    })?;
    if !v.iter().all(|x| x.is_finite()) {
        return Err(value_error(format!("{what}: {v:?} is not finite")));
    }
    Ok(v)
}

impl Tracker {
    fn inner(&mut self) -> PyResult<&mut tracker::Tracker<CoreLink>> {
        self.slot()?
            .as_mut()
            .ok_or_else(|| TrackerError::new_err("the tracker was finished: make a new one"))
    }

    /// The tracker's events into the reports and poses kept for `poll` and `poll_poses`
    /// (none once it is finished: `finish` kept its last).
    fn take_events(&mut self) -> PyResult<()> {
        let events: Vec<Event> = match self.slot()? {
            Some(t) => t.poll().collect(),
            None => return Ok(()),
        };
        self.keep(events);
        Ok(())
    }

    /// Events into the reports and poses kept for `poll` and `poll_poses`.
    fn keep(&mut self, events: Vec<Event>) {
        for e in events {
            match e {
                Event::Frame(f) => self.reports.push(FrameReport {
                    index: f.index,
                    t: f.t_us as f64 * 1e-6,
                    pose: f.pose.map(|camera| Pose {
                        camera,
                        t: Some(f.t_us as f64 * 1e-6),
                        cov: f.cov,
                    }),
                    tracked: f.tracked,
                    correspondences: f.correspondences,
                    weak: f.weak.map(|w| w.name()),
                    skipped: None,
                }),
                Event::FrameSkipped { index, why } => self.reports.push(FrameReport {
                    index,
                    t: f64::NAN,
                    pose: None,
                    tracked: None,
                    correspondences: 0,
                    weak: None,
                    skipped: Some(why),
                }),
                Event::Pose(p) => {
                    if self.poses.len() == MAX_POSES {
                        self.poses.pop_front();
                    }
                    self.poses.push_back(Pose {
                        camera: p.camera,
                        t: Some(p.t_us as f64 * 1e-6),
                        cov: p.cov,
                    });
                }
                // Details are told only to a tracker asked for them (this one is not); none
                // is missed, as this module polls after every push.
                Event::Located { .. } | Event::State(_) | Event::Detail(_) | Event::Missed(_) => {}
            }
        }
    }

    fn slot(&mut self) -> PyResult<&mut Option<tracker::Tracker<CoreLink>>> {
        self.inner
            .get_mut()
            .map_err(|_| TrackerError::new_err("the tracker failed inside: make a new one"))
    }

    /// The tracker of `model` from the constructor's arguments.
    #[allow(clippy::too_many_arguments)]
    fn builder(
        model: &Model,
        camera: &Camera,
        start: Start,
        imu: Option<&Imu>,
        rate_hz: Option<f64>,
        cache: Option<PathBuf>,
        live: bool,
        latency_s: f64,
    ) -> PyResult<TrackerBuilder> {
        let rate = rate_hz.or(camera.rate_hz).ok_or_else(|| {
            value_error("give the camera's frame rate (rate_hz=…): its calibration file has none")
        })?;
        let mut builder = TrackerBuilder::new(camera.inner, (*model.inner).clone())
            .frame_rate_hz(rate)
            .start(start)
            .live(live);
        if let Some(cache) = cache {
            builder = builder.cache(cache);
        }
        if let Some(imu) = imu {
            let t_bs = imu.t_bs.or(camera.t_bs).ok_or_else(|| {
                value_error("the camera's mount on the IMU is needed: give Imu(t_bs=…) or a camera from a calibration file with T_BS")
            })?;
            check_rigid(&t_bs).map_err(|e| value_error(format!("t_bs: {e}")))?;
            let hand_eye = HandEye::from_t_bs(&t_bs)
                .ok_or_else(|| value_error("t_bs is not a rigid transform"))?;
            let rig = Rig {
                imu_rate_hz: imu.rate_hz,
                imu_noise: imu.noise,
                camera_rate_hz: Some(rate),
                hand_eye,
            };
            builder = builder.imu(imu.filter, rig).latency_s(latency_s);
        }
        Ok(builder)
    }
}

#[pymethods]
impl Tracker {
    /// A tracker of `model` seen by `camera` (see the stub).
    #[new]
    #[pyo3(signature = (model, camera, start_pose = None, imu = None, *, rate_hz = None, link = "inproc", cache = None, live = false, latency_s = 0.0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        model: &Model,
        camera: &Camera,
        start_pose: Option<&Bound<'_, PyAny>>,
        imu: Option<&Imu>,
        rate_hz: Option<f64>,
        link: &str,
        cache: Option<PathBuf>,
        live: bool,
        latency_s: f64,
    ) -> PyResult<Self> {
        let start = match start_pose {
            None => Start::Locate,
            Some(p) => Start::Camera(start_pose_of(p)?),
        };
        let spec = LinkSpec::from_str(link)
            .map_err(|e| value_error(format!("link: {e} (one of {})", core_link::LINK_FORMS)))?;
        if spec == LinkSpec::QemuDefault {
            return Err(value_error(
                "link \"qemu\": name the firmware image, qemu:PATH (the command line finds the repository's)",
            ));
        }
        let builder = Self::builder(model, camera, start, imu, rate_hz, cache, live, latency_s)?;
        let inner = py
            .detach(move || builder.build_with(CoreLink::open(&spec)?))
            .map_err(of_tracker)?;
        Ok(Tracker {
            inner: Mutex::new(Some(inner)),
            next_index: 0,
            reports: Vec::new(),
            poses: VecDeque::new(),
        })
    }

    /// Pushes a frame taken at `t` [s]: `uint8`, grey `H×W` or colour `H×W×3` (see the stub).
    #[pyo3(signature = (t, image, *, index = None, channels = "bgr"))]
    fn push_frame(
        &mut self,
        py: Python<'_>,
        t: f64,
        image: &Bound<'_, PyAny>,
        index: Option<usize>,
        channels: &str,
    ) -> PyResult<()> {
        let index = index.unwrap_or(self.next_index);
        let what = format!("frame {index}");
        let t_ns = nanos(t, &what)?;
        let gray = gray_of(image, Channels::parse(channels)?, &what)?;
        let tracker = self.inner()?;
        py.detach(|| tracker.push_frame(tracker::Frame::decoded(index, t_ns, gray)))
            .map_err(of_tracker)?;
        self.next_index = index + 1;
        Ok(())
    }

    /// Pushes an IMU sample taken at `t` [s ≥ 0]: angular rate [rad/s] and specific force
    /// [m/s²], each 3 numbers in the IMU's frame.
    fn push_imu(
        &mut self,
        py: Python<'_>,
        t: f64,
        gyro: &Bound<'_, PyAny>,
        accel: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let t_ns = nanos(t, "IMU sample")?;
        let t_ns = u64::try_from(t_ns)
            .map_err(|_| value_error(format!("IMU sample: time {t} s is before 0")))?;
        let sample = tracker::ImuSample {
            t_ns,
            gyro: vector3(gyro, "gyro")?,
            accel: vector3(accel, "accel")?,
        };
        let tracker = self.inner()?;
        py.detach(|| tracker.push_imu(sample)).map_err(of_tracker)
    }

    /// The reports of the frames done since the last call, in order (after `finish`, the
    /// last ones).
    fn poll(&mut self) -> PyResult<Vec<FrameReport>> {
        self.take_events()?;
        Ok(std::mem::take(&mut self.reports))
    }

    /// The core's poses since the last call, in order (with an IMU one per sample; without,
    /// two per frame: the prediction and the update). The newest 4096 are kept.
    fn poll_poses(&mut self) -> PyResult<Vec<Pose>> {
        self.take_events()?;
        Ok(self.poses.drain(..).collect())
    }

    /// The core's latest pose, or None before it has one.
    #[getter]
    fn pose(&mut self) -> PyResult<Option<Pose>> {
        Ok(self.inner()?.latest().map(|p| Pose {
            camera: p.camera,
            t: Some(p.t_us as f64 * 1e-6),
            cov: p.cov,
        }))
    }

    /// `"locating"`, `"starting"`, `"tracking"` or `"lost"`.
    #[getter]
    fn state(&mut self) -> PyResult<&'static str> {
        Ok(match self.inner()?.state() {
            tracker::State::Locating => "locating",
            tracker::State::Starting => "starting",
            tracker::State::Tracking => "tracking",
            tracker::State::Lost => "lost",
        })
    }

    /// The renderer's adapter (GPU, or the software driver).
    #[getter]
    fn adapter(&mut self) -> PyResult<String> {
        Ok(self.inner()?.adapter().to_string())
    }

    /// Searches for the model again from the next frame (the pose is known to be wrong).
    fn relocate(&mut self) -> PyResult<()> {
        self.inner()?.relocate().map_err(of_tracker)
    }

    /// Ends the run (what is in flight is finished; its last reports and poses are kept for
    /// `poll` and `poll_poses`) and returns its figures: `tracked` and `judged` frames and
    /// their `share`.
    fn finish<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let tracker = self
            .slot()?
            .take()
            .ok_or_else(|| TrackerError::new_err("the tracker was finished already"))?;
        let mut done = py.detach(move || tracker.finish());
        self.keep(std::mem::take(&mut done.events));
        done.result.map_err(of_tracker)?;
        let tracker::Tally { tracked, judged } = done.tally;
        let d = PyDict::new(py);
        d.set_item("tracked", tracked)?;
        d.set_item("judged", judged)?;
        // No frame judged (none analysed): no share.
        d.set_item(
            "share",
            (judged > 0).then(|| tracked as f64 / judged as f64),
        )?;
        Ok(d)
    }

    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    /// Finishes the run on leaving a `with` block (its figures are dropped; call `finish`
    /// for them).
    fn __exit__(
        &mut self,
        py: Python<'_>,
        _kind: Option<&Bound<'_, PyAny>>,
        _value: Option<&Bound<'_, PyAny>>,
        _traceback: Option<&Bound<'_, PyAny>>,
    ) -> bool {
        if let Ok(Some(t)) = self.slot().map(Option::take) {
            py.detach(move || drop(t.finish()));
        }
        false
    }
}
