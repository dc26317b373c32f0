//! Runs a simulated scenario through a [`Device`] in lock-step: IMU samples in time order,
//! each camera frame's correspondences delivered a configurable number of IMU samples after its
//! trigger (so the delayed-update path is always exercised).

use std::collections::VecDeque;

use firmware_sim::sim::camera::{self, Mount, Pinhole};
use firmware_sim::sim::imu::{ImuNoise, ImuReading, ImuSim};
use firmware_sim::sim::trajectory::{Kinematics, Trajectory};
use fusion_core::{Device, Kernels, Scalar};
use nalgebra::{UnitQuaternion, Vector2, Vector3};
use protocol::{
    Config, ContourPoint, CoreToHost, Correspondence, ErrorCode, Hello, HostToCore, ImuSample,
    Init, Mode, PROTOCOL_VERSION, Status, Tick, UpdateOutcome, UpdateReport, frame_messages,
};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

/// Everything that defines one simulated run.
pub struct Scenario {
    /// Ground-truth motion of the IMU.
    pub trajectory: Box<dyn Trajectory>,
    /// IMU rate [Hz].
    pub imu_rate_hz: f64,
    /// IMU samples per camera frame (the camera is triggered by the IMU).
    pub camera_every: usize,
    /// IMU samples between a trigger and the arrival of its correspondences.
    pub latency_samples: usize,
    /// IMU noise.
    pub noise: ImuNoise,
    /// Initial gyro bias [rad/s].
    pub gyro_bias: Vector3<f64>,
    /// Initial accelerometer bias [m/s²].
    pub accel_bias: Vector3<f64>,
    /// Camera mount.
    pub mount: Mount,
    /// Camera intrinsics.
    pub camera: Pinhole,
    /// Model points.
    pub points: Vec<Vector3<f64>>,
    /// Registration noise [px].
    pub pixel_sigma: f64,
    /// Most correspondences per frame.
    pub max_correspondences: usize,
    /// Time spans [s] without any correspondence (the model out of view).
    pub blind: Vec<(f64, f64)>,
    /// Error of the 3D model against the real scene [m]: registrations come from the scene,
    /// 3D points from the model.
    pub model_offset: Vector3<f64>,
    /// Filter configuration.
    pub config: Config,
    /// Initialisation request (it may be deliberately wrong).
    pub init: Init,
    /// Seed of all noise.
    pub seed: u64,
    /// Which kind of correspondence the host sends.
    pub measure: Measure,
}

/// Which kind of correspondence the simulated host sends (protocol 3.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Measure {
    /// 2D/3D correspondences (eq. 10).
    Points,
    /// Each registration seen along a contour normal of random direction (eq. 10c): one degree
    /// of freedom per point, as a silhouette edge gives.
    Contours,
    /// Every other registration as a contour, in the same frame.
    Both,
}

/// One correspondence's prediction error, measured by the harness.
#[derive(Clone, Copy, Debug)]
pub struct PredictionError {
    /// Trigger time [s].
    pub t: f64,
    /// Distance between the projection at the predicted pose and the registered point [px].
    pub px: f64,
}

/// What the device answered over a run.
#[derive(Debug, Default)]
pub struct Outcome {
    /// Per correspondence sent, at the pose the core predicted before the update.
    pub prediction_errors: Vec<PredictionError>,
    /// Every update report.
    pub reports: Vec<UpdateReport>,
    /// Every status change.
    pub statuses: Vec<Status>,
    /// Every error message.
    pub errors: Vec<ErrorCode>,
    /// Pose predictions received.
    pub predictions: usize,
    /// Correspondences sent.
    pub sent: usize,
    /// Sampling reports of a core that samples its own IMU.
    pub sampling: Vec<protocol::SamplingReport>,
}

impl Outcome {
    /// Mean prediction error [px] of the correspondences sent after `t0`.
    pub fn mean_prediction_error(&self, t0: f64) -> f64 {
        let v: Vec<f64> = self
            .prediction_errors
            .iter()
            .filter(|e| e.t >= t0)
            .map(|e| e.px)
            .collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    }

    /// Correspondences accepted and rejected over all reports.
    pub fn accepted_rejected(&self) -> (usize, usize) {
        self.reports.iter().fold((0, 0), |(a, r), rep| {
            (a + rep.accepted as usize, r + rep.rejected as usize)
        })
    }
}

/// A pending camera frame: its prediction and its true pose.
struct Pending {
    deliver_at: usize,
    frame_id: u32,
    t_us: u64,
    truth: Kinematics,
    c_w: Vector3<f64>,
    q_cw: UnitQuaternion<f64>,
}

/// `q_ws` of the truth as the core's `q_sw` `[w, x, y, z]`.
pub fn q_sw_of(k: &Kinematics) -> [f64; 4] {
    let q = k.q_ws.inverse().into_inner();
    [q.w, q.i, q.j, q.k]
}

/// The sample's time stamp [µs].
pub fn t_us(k: usize, rate_hz: f64) -> u64 {
    (k as f64 * 1e6 / rate_hz).round() as u64
}

/// Drives a device through a scenario one step at a time; [`run`] is this in a loop, and the
/// fault tests use it to interleave bad input.
pub struct Driver<'s, T: Scalar> {
    /// The scenario.
    pub sc: &'s Scenario,
    /// The device under test.
    pub device: Device<T>,
    /// Everything the device answered.
    pub out: Outcome,
    imu: ImuSim,
    rng: StdRng,
    pending: VecDeque<Pending>,
    /// Next IMU sample index.
    pub k: usize,
    /// Truth and reading of the last sample sent.
    pub last: Option<(Kinematics, ImuReading)>,
    /// Whether predicted frames get their correspondences.
    pub answer_frames: bool,
    /// When set, every message sent and every answer, in order (for replay to another core).
    pub transcript: Option<(Vec<HostToCore>, Vec<CoreToHost>)>,
}

impl<'s, T: Kernels> Driver<'s, T> {
    /// Opens the session: `Hello`, `Configure`, `Init`.
    pub fn new(sc: &'s Scenario) -> Self {
        let mut d = Driver {
            sc,
            device: Device::new(),
            out: Outcome::default(),
            imu: ImuSim::new(
                sc.noise,
                sc.imu_rate_hz,
                sc.gyro_bias,
                sc.accel_bias,
                sc.seed,
            ),
            rng: StdRng::seed_from_u64(sc.seed ^ 0xC0FFEE),
            pending: VecDeque::new(),
            k: 0,
            last: None,
            answer_frames: true,
            transcript: None,
        };
        d.send(&HostToCore::Hello(Hello {
            version: PROTOCOL_VERSION,
        }));
        d.send(&HostToCore::Configure(sc.config));
        d.send(&HostToCore::Init(sc.init));
        d
    }

    /// Sends one message; returns what the device answered (also recorded in `out`).
    pub fn send(&mut self, msg: &HostToCore) -> Vec<CoreToHost> {
        let mut answers = Vec::new();
        self.device.handle(msg, &mut |m| answers.push(m));
        if let Some((sent, got)) = &mut self.transcript {
            sent.push(msg.clone());
            got.extend(answers.iter().cloned());
        }
        self.record(&answers);
        answers
    }

    /// Records the device's answers in [`Driver::out`].
    pub fn record(&mut self, answers: &[CoreToHost]) {
        for m in answers {
            match m {
                CoreToHost::PosePrediction(_) => self.out.predictions += 1,
                CoreToHost::UpdateReport(r) => self.out.reports.push(r.clone()),
                CoreToHost::Status(s) => self.out.statuses.push(*s),
                CoreToHost::Error(e) => self.out.errors.push(e.code),
                CoreToHost::Sampling(r) => self.out.sampling.push(*r),
                CoreToHost::HelloAck(_)
                | CoreToHost::State(_)
                | CoreToHost::Trigger(_)
                | CoreToHost::RawImu(_) => {}
            }
        }
    }

    /// The next IMU sample of the scenario as a message (not sent); for the vision-only
    /// model, a `Tick` at its time instead.
    pub fn next_imu(&mut self) -> HostToCore {
        let sc = self.sc;
        let t = self.k as f64 / sc.imu_rate_hz;
        let truth = sc.trajectory.at(t);
        let reading = self.imu.read(&truth);
        self.last = Some((truth, reading));
        let f = |v: Vector3<f64>| [v[0] as f32, v[1] as f32, v[2] as f32];
        let (t_us, trigger) = (
            t_us(self.k, sc.imu_rate_hz),
            self.k.is_multiple_of(sc.camera_every),
        );
        let msg = if sc.config.model.has_imu() {
            HostToCore::Imu(ImuSample {
                t_us,
                gyro: f(reading.gyro),
                accel: f(reading.accel),
                trigger,
            })
        } else {
            HostToCore::Tick(Tick { t_us, trigger })
        };
        self.k += 1;
        msg
    }

    /// Sends the next IMU sample, then the correspondences of every frame now due.
    pub fn step(&mut self) {
        let msg = self.next_imu();
        let answers = self.send(&msg);
        self.answer(answers);
    }

    /// Sends `sample` in place of the next IMU sample of the scenario (whose truth still
    /// drives the frames), then the correspondences of every frame now due: the replay of
    /// samples taken elsewhere (a board's) through the host.
    pub fn step_with(&mut self, sample: ImuSample) {
        let _ = self.next_imu();
        let answers = self.send(&HostToCore::Imu(sample));
        self.answer(answers);
    }

    /// Takes the device's answers to the sample just sent: predictions become pending frames,
    /// and the frames now due get their correspondences.
    pub fn answer(&mut self, answers: Vec<CoreToHost>) {
        let k = self.k - 1;
        let Some((truth, _)) = self.last else { return };
        for answer in answers {
            if let CoreToHost::PosePrediction(p) = answer {
                let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                    p.q_cw[0] as f64,
                    p.q_cw[1] as f64,
                    p.q_cw[2] as f64,
                    p.q_cw[3] as f64,
                ));
                self.pending.push_back(Pending {
                    deliver_at: k + self.sc.latency_samples,
                    frame_id: p.frame_id,
                    t_us: p.t_us,
                    truth,
                    c_w: Vector3::new(p.c_w[0] as f64, p.c_w[1] as f64, p.c_w[2] as f64),
                    q_cw: q,
                });
            }
        }
        while self.pending.front().is_some_and(|p| p.deliver_at <= k) {
            let Some(p) = self.pending.pop_front() else {
                break;
            };
            if self.answer_frames {
                self.deliver(&p);
            }
        }
    }

    /// The correspondences of a true pose, as the host would register them.
    pub fn observe(&mut self, truth: &Kinematics) -> Vec<Correspondence> {
        let sc = self.sc;
        if sc.blind.iter().any(|&(a, b)| truth.t >= a && truth.t < b) {
            return Vec::new();
        }
        let mut corrs = camera::observe(
            &sc.points,
            truth,
            &sc.mount,
            &sc.camera,
            sc.pixel_sigma,
            sc.max_correspondences,
            &mut self.rng,
        );
        for c in &mut corrs {
            for k in 0..3 {
                c.m_w[k] += sc.model_offset[k] as f32;
            }
        }
        corrs
    }

    fn deliver(&mut self, p: &Pending) {
        let corrs = self.observe(&p.truth);
        for c in &corrs {
            let m_w = Vector3::new(c.m_w[0] as f64, c.m_w[1] as f64, c.m_w[2] as f64);
            let pc = p.q_cw * (m_w - p.c_w);
            if pc[2] > 1e-3 {
                let proj = Vector2::new(pc[0] / pc[2], pc[1] / pc[2]);
                let reg = Vector2::new(c.m_n[0] as f64, c.m_n[1] as f64);
                self.out.prediction_errors.push(PredictionError {
                    t: p.truth.t,
                    px: (proj - reg).norm() * self.sc.camera.fx,
                });
            }
        }
        self.out.sent += corrs.len();
        let (points, contours) = self.as_measured(&corrs);
        let msgs: Vec<HostToCore> = frame_messages(p.frame_id, p.t_us, &points, &contours)
            .expect("within the protocol's per-frame bound")
            .collect();
        for msg in msgs {
            self.send(&msg);
        }
    }

    /// The registrations as the scenario's [`Measure`] sends them: a contour keeps a
    /// registration's component along a normal of random direction, with the registration's
    /// variance along it.
    fn as_measured(
        &mut self,
        corrs: &[Correspondence],
    ) -> (Vec<Correspondence>, Vec<ContourPoint>) {
        let mut points = Vec::new();
        let mut contours = Vec::new();
        for (i, c) in corrs.iter().enumerate() {
            let contour = match self.sc.measure {
                Measure::Points => false,
                Measure::Contours => true,
                Measure::Both => i % 2 == 1,
            };
            if !contour {
                points.push(*c);
                continue;
            }
            let angle: f64 = self.rng.random_range(0.0..std::f64::consts::TAU);
            let n = [angle.cos() as f32, angle.sin() as f32];
            contours.push(ContourPoint {
                m_w: c.m_w,
                cov_w: c.cov_w,
                n,
                d: n[0] * c.m_n[0] + n[1] * c.m_n[1],
                // Isotropic registrations: the variance along any normal.
                var_d: c.cov_n[0],
            });
        }
        (points, contours)
    }

    /// Continues the same run against another scenario (for example a changed scene); the
    /// IMU, noise and pending frames carry over.
    pub fn switch_scenario<'t>(self, sc: &'t Scenario) -> Driver<'t, T> {
        Driver {
            sc,
            device: self.device,
            out: self.out,
            imu: self.imu,
            rng: self.rng,
            pending: self.pending,
            k: self.k,
            last: self.last,
            answer_frames: self.answer_frames,
            transcript: self.transcript,
        }
    }

    /// Samples in the scenario.
    pub fn samples(&self) -> usize {
        (self.sc.trajectory.duration() * self.sc.imu_rate_hz) as usize
    }
}

/// Runs the scenario; `each` sees the device after every IMU sample with the truth.
pub fn run<T: Kernels>(
    sc: &Scenario,
    mut each: impl FnMut(&Device<T>, &Kinematics, &ImuReading),
) -> Outcome {
    let mut d = Driver::<T>::new(sc);
    for _ in 0..d.samples() {
        d.step();
        if let Some((truth, reading)) = d.last {
            each(&d.device, &truth, &reading);
        }
    }
    d.out
}

/// Whether the run ended tracking (not diverged, not re-initialising).
pub fn tracking_at_end<T: Scalar>(device: &Device<T>) -> bool {
    matches!(device.mode(), Mode::Tracking | Mode::DeadReckoning)
}

/// Counts reports with the given outcome.
pub fn count_outcome(out: &Outcome, outcome: UpdateOutcome) -> usize {
    out.reports.iter().filter(|r| r.outcome == outcome).count()
}

/// Building blocks of the standard test scenes.
pub mod scenes {
    use super::*;
    use firmware_sim::sim::trajectory::{Harmonic, Ramp, Sines};
    use nalgebra::{Matrix3, Rotation3};
    use protocol::{InitAttitude, ModelKind, NoiseParams};

    /// Camera looking along the sensor's x axis (sensor: x forward, y left, z up; camera: z
    /// forward, x right, y down), 5 cm in front of the IMU.
    pub fn forward_mount() -> Mount {
        let r_cs = Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
        Mount {
            q_cs: UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r_cs)),
            c_s: Vector3::new(0.05, 0.0, 0.02),
        }
    }

    /// A textured wall 2 m in front of the rest pose (plane x = 2), 4 × 3 m.
    pub fn wall() -> Vec<Vector3<f64>> {
        camera::wall_points(2.0, (-2.0, 2.0), (-0.5, 2.5), (16, 12))
    }

    /// Hand-held motion in front of the wall: rests `rest` seconds, then moves with peak
    /// accelerations of about `accel` m/s².
    pub fn handheld(length: f64, rest: f64, accel: f64) -> Harmonic {
        // a = A (2πf)²: amplitudes that give the requested peak at these frequencies.
        let amp = |f: f64, share: f64| share * accel / (2.0 * std::f64::consts::PI * f).powi(2);
        let s = |terms: Vec<(f64, f64, f64)>| Sines { terms };
        Harmonic {
            centre: Vector3::new(0.0, 0.0, 1.0),
            position: [
                s(vec![(amp(0.7, 0.4), 0.7, 0.0), (amp(1.9, 0.3), 1.9, 1.0)]),
                s(vec![(amp(0.5, 0.5), 0.5, 0.3), (amp(1.3, 0.3), 1.3, 2.0)]),
                s(vec![(amp(0.6, 0.4), 0.6, 1.2), (amp(2.3, 0.2), 2.3, 0.5)]),
            ],
            attitude0: [0.0, 0.0, 0.0],
            attitude: [
                s(vec![(0.25, 0.3, 0.0), (0.05, 1.1, 1.0)]),
                s(vec![(0.12, 0.45, 0.7), (0.04, 1.4, 0.2)]),
                s(vec![(0.15, 0.35, 2.0), (0.05, 1.7, 1.3)]),
            ],
            ramp: Ramp {
                start: rest,
                length: 1.0,
            },
            length,
        }
    }

    /// Noise settings for a model on the hand-held motion (the paper tuned them per model:
    /// the constant-velocity models need a much larger motion noise).
    pub fn config(model: ModelKind, imu_rate_hz: f64, accel: f64) -> Config {
        let mut c = protocol::samples::config();
        c.model = model;
        c.imu_rate_hz = imu_rate_hz as f32;
        c.camera_rate_hz = 25.0;
        c.hand_eye = forward_mount().to_wire();
        let (gs, as_) = ImuNoise::MT9.sample_sigmas(imu_rate_hz);
        c.noise = NoiseParams {
            motion: match model {
                // White jerk of the harmonic motion: peak jerk ≈ a · 2πf.
                ModelKind::Acc => (accel * 8.0).max(1.0) as f32,
                _ => (accel * 1.5).max(0.5) as f32,
            },
            angular: 3.0,
            gyro_bias_walk: (ImuNoise::MT9.gyro_walk * 5.0) as f32,
            accel_bias_walk: (ImuNoise::MT9.accel_walk * 5.0) as f32,
            gyro_meas: (gs * 1.5) as f32,
            accel_meas: match model {
                // The gravity model's accelerometer noise absorbs the free acceleration.
                ModelKind::Gravity => (accel * 0.7).max(0.3) as f32,
                _ => (as_ * 1.5) as f32,
            },
        };
        c.gate = 30.0;
        // Dead reckoning with a large motion noise grows the covariance fast: the divergence
        // threshold must leave room for a few frames without vision.
        c.divergence.covariance_frobenius = (2.0 * c.noise.motion * c.noise.motion).max(10.0);
        c.still_samples = (imu_rate_hz * 0.5) as u16;
        c.state_every = 0;
        c
    }

    /// The standard scenario for `model`: hand-held motion in front of the wall, 200 Hz IMU,
    /// 25 Hz camera (every 8th sample), 60 ms latency, true initial pose given (its position
    /// and yaw to the inertial models, all of it to vision-only, which ticks at the IMU's
    /// rate).
    pub fn standard(model: ModelKind, length: f64, accel: f64, seed: u64) -> Scenario {
        let trajectory = handheld(length, 1.0, accel);
        let k0 = trajectory.at(0.0);
        let yaw = k0.q_ws.euler_angles().2;
        let attitude = if model.has_imu() {
            InitAttitude::GravityAndYaw(yaw as f32)
        } else {
            InitAttitude::Full(q_sw_of(&k0).map(|v| v as f32))
        };
        Scenario {
            trajectory: Box::new(trajectory),
            imu_rate_hz: 200.0,
            camera_every: 8,
            latency_samples: 12,
            noise: ImuNoise::MT9,
            gyro_bias: Vector3::zeros(),
            accel_bias: Vector3::zeros(),
            mount: forward_mount(),
            camera: Pinhole::PAPER,
            points: wall(),
            pixel_sigma: 0.5,
            max_correspondences: 30,
            blind: Vec::new(),
            model_offset: Vector3::zeros(),
            config: config(model, 200.0, accel),
            init: Init {
                position: [k0.p_w[0] as f32, k0.p_w[1] as f32, k0.p_w[2] as f32],
                attitude,
            },
            seed,
            measure: Measure::Points,
        }
    }
}

/// Errors of the live filter against the truth.
pub mod errors {
    use super::*;
    use fusion_core::state::{ACC_BIAS, GYRO_BIAS, POS};

    /// Position error [m].
    pub fn position<T: Scalar>(d: &Device<T>, k: &Kinematics) -> f64 {
        let p = d.filter().st.v3(POS);
        let p = Vector3::new(to64(p[0]), to64(p[1]), to64(p[2]));
        (p - k.p_w).norm()
    }

    /// The filter's orientation `q_sw` as an f64 unit quaternion.
    fn estimated_q_sw<T: Scalar>(d: &Device<T>) -> UnitQuaternion<f64> {
        let q = d.filter().st.q();
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            to64(q[0]),
            to64(q[1]),
            to64(q[2]),
            to64(q[3]),
        ))
    }

    /// Attitude error [rad] (angle of `q_est⁻¹ q_true`).
    pub fn attitude<T: Scalar>(d: &Device<T>, k: &Kinematics) -> f64 {
        // The filter holds q_sw; the truth q_ws.
        (estimated_q_sw(d) * k.q_ws).angle()
    }

    /// Tilt error [rad]: angle between estimated and true gravity directions in the sensor.
    pub fn tilt<T: Scalar>(d: &Device<T>, k: &Kinematics) -> f64 {
        let up_est = estimated_q_sw(d) * Vector3::z();
        let up_true = k.q_ws.inverse() * Vector3::z();
        up_est.angle(&up_true)
    }

    /// Gyro and accelerometer bias errors [rad/s, m/s²].
    pub fn biases<T: Scalar>(d: &Device<T>, r: &ImuReading) -> (f64, f64) {
        let st = &d.filter().st;
        let g = st.v3(GYRO_BIAS);
        let a = st.v3(ACC_BIAS);
        let g = Vector3::new(to64(g[0]), to64(g[1]), to64(g[2]));
        let a = Vector3::new(to64(a[0]), to64(a[1]), to64(a[2]));
        ((g - r.gyro_bias).norm(), (a - r.accel_bias).norm())
    }

    /// Scalar to f64.
    pub fn to64<T: Scalar>(x: T) -> f64 {
        x.to_f64()
    }
}
