//! The fusion core on real data: EuRoC `imu_april` (real 200 Hz IMU, real AprilGrid corner
//! detections of cam1 as 2D/3D correspondences, the dataset's calibration). Reports, per
//! model and correspondence latency (5 ms and 50 ms), the paper's prediction error in pixels,
//! the share of correspondences gated out and the divergences (issue 18). The grid leaves the
//! view at 55.8 s for 1.2 s while the rig moves: every model dead-reckons through the gap and
//! snaps on again without diverging. Skips with a message when `../shared/data` is absent.

use std::path::{Path, PathBuf};

use fusion_core::Device;
use host_vision::camera::{Camera, read_euroc_sensor_yaml};
use host_vision::features::correspondence::pixel_to_normalised;
use nalgebra::{DMatrix, Matrix2, Matrix3, Rotation3, UnitQuaternion, Vector2, Vector3};
use protocol::{
    Config, CoreToHost, Correspondence, Correspondences, Hello, HostToCore, ImuSample, Init,
    InitAttitude, Mode, ModelKind, PROTOCOL_VERSION,
};

fn data_dir() -> Option<PathBuf> {
    let d = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/euroc-imu-april");
    d.join("imu0.csv").exists().then_some(d)
}

/// Undistorted normalised points with their grid points.
type Observations = Vec<(Vector2<f64>, Vector3<f64>)>;

/// Hand-held motion, the physics behind the process noises (docs/FILTER.md §4, eq. 7 / 12 / 15, and
/// docs/notes/issue18-robustness.md): the largest linear acceleration of the rig [m/s²] (the
/// figure the initial σ below already assumes; in this sequence the accelerometer's magnitude
/// departs from g by at most 5.2 m/s² in 99 % of the samples) and the largest angular
/// acceleration [rad/s²] (the gyro's rate differentiated sample to sample: 27 rad/s² at the
/// 99th percentile, 46 at most). A white-noise rate model observed every `T` gets the density
/// `q = a_max √T` (Bar-Shalom, Li & Kirubarajan 2001, §6.2.2): the rate it integrates changes
/// by about `a_max T` between observations.
const HAND_ACCEL: f64 = 5.0;
const HAND_ANGULAR_ACCEL: f64 = 30.0;

struct Imu {
    t_ns: i64,
    gyro: Vector3<f64>,
    accel: Vector3<f64>,
}

struct Frame {
    t_ns: i64,
    /// Distorted pixel and grid point.
    obs: Vec<(Vector2<f64>, Vector3<f64>)>,
}

fn read_imu(path: &Path) -> Vec<Imu> {
    std::fs::read_to_string(path)
        .expect("imu0.csv")
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l
                .split(',')
                .map(|x| x.trim().parse().expect("number"))
                .collect();
            Imu {
                t_ns: l.split(',').next().unwrap().trim().parse().unwrap(),
                gyro: Vector3::new(v[1], v[2], v[3]),
                accel: Vector3::new(v[4], v[5], v[6]),
            }
        })
        .collect()
}

fn read_frames(dir: &Path) -> Vec<Frame> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("cam1")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
        .collect();
    files.sort();
    files
        .iter()
        .filter_map(|f| {
            let t_ns: i64 = f.file_stem()?.to_str()?.parse().ok()?;
            let obs = std::fs::read_to_string(f)
                .ok()?
                .lines()
                .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
                .map(|l| {
                    let v: Vec<f64> = l.split(',').map(|x| x.trim().parse().unwrap()).collect();
                    (Vector2::new(v[5], v[6]), Vector3::new(v[7], v[8], v[9]))
                })
                .collect();
            Some(Frame { t_ns, obs })
        })
        .collect()
}

/// `key: value` of a flat YAML file.
fn yaml_number(path: &Path, key: &str) -> f64 {
    let text = std::fs::read_to_string(path).expect("yaml");
    text.lines()
        .find_map(|l| {
            let (k, v) = l.split_once(':')?;
            (k.trim() == key).then(|| v.split('#').next().unwrap().trim().parse().unwrap())
        })
        .unwrap_or_else(|| panic!("{key} in {}", path.display()))
}

/// Pose of a planar target (z = 0) from normalised image points: homography by DLT, then
/// `H ∝ [r1 r2 t]`. Returns `(R_cg, t_cg)`.
fn planar_pose(obs: &[(Vector2<f64>, Vector3<f64>)]) -> (Matrix3<f64>, Vector3<f64>) {
    let mut a = DMatrix::zeros(2 * obs.len(), 9);
    for (i, (m, p)) in obs.iter().enumerate() {
        let (x, y, gx, gy) = (m[0], m[1], p[0], p[1]);
        let r0 = [gx, gy, 1.0, 0.0, 0.0, 0.0, -x * gx, -x * gy, -x];
        let r1 = [0.0, 0.0, 0.0, gx, gy, 1.0, -y * gx, -y * gy, -y];
        for c in 0..9 {
            a[(2 * i, c)] = r0[c];
            a[(2 * i + 1, c)] = r1[c];
        }
    }
    let svd = a.svd(false, true);
    let vt = svd.v_t.unwrap();
    let (imin, _) = svd
        .singular_values
        .iter()
        .enumerate()
        .fold((0, f64::MAX), |m, (i, &s)| if s < m.1 { (i, s) } else { m });
    let h = vt.row(imin);
    let hm = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let mut lambda = 1.0 / hm.column(0).norm();
    if hm[(2, 2)] * lambda < 0.0 {
        lambda = -lambda;
    }
    let r1 = hm.column(0) * lambda;
    let r2 = hm.column(1) * lambda;
    let r = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let svd = r.svd(true, true);
    let r = svd.u.unwrap() * svd.v_t.unwrap();
    (r, hm.column(2) * lambda)
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

struct Row {
    model: ModelKind,
    latency_ms: u32,
    /// Largest Frobenius norm of the covariance.
    max_cov: f32,
    mean_px: f64,
    median_px: f64,
    gated: f64,
    frames: usize,
    divergences: Vec<(f64, protocol::StatusReason)>,
}

/// IMU rate of the sequence [Hz].
const IMU_RATE: f64 = 200.0;

/// One frame's time stamp [ns], undistorted normalised observations and the covariance of
/// each.
type Undistorted = (i64, Observations, Vec<Matrix2<f64>>);

/// The dataset's calibration of cam1 and the IMU.
struct Rig {
    /// cam1: intrinsics and distortion.
    cam: Camera,
    /// Camera → sensor (IMU) rotation.
    q_cs: UnitQuaternion<f64>,
    /// The same rotation as a matrix.
    r_cs: Matrix3<f64>,
    /// Camera centre in the sensor frame.
    c_s: Vector3<f64>,
    /// Gyro noise σ per reading at [`IMU_RATE`] [rad/s].
    gyro_sigma: f64,
    /// Accelerometer noise σ per reading at [`IMU_RATE`] [m/s²].
    accel_sigma: f64,
    /// Gyro bias random walk (the dataset's density).
    gyro_walk: f64,
    /// Accelerometer bias random walk (the dataset's density).
    accel_walk: f64,
}

/// Reads cam1's calibration and mounting and the IMU's noise from the data folder.
fn read_rig(dir: &Path) -> Rig {
    let calib = read_euroc_sensor_yaml(&dir.join("cam1-sensor.yaml")).expect("cam1 calibration");
    let cam = calib.camera;
    let t_bs = calib.extrinsics.expect("T_BS");
    let r_bc = t_bs.fixed_view::<3, 3>(0, 0).into_owned();
    let c_s = t_bs.fixed_view::<3, 1>(0, 3).into_owned();
    let r_cs = r_bc.transpose();
    let q_cs = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r_cs));
    let imu_yaml = dir.join("imu0-sensor.yaml");
    let rate = IMU_RATE;
    Rig {
        cam,
        q_cs,
        r_cs,
        c_s,
        gyro_sigma: yaml_number(&imu_yaml, "gyroscope_noise_density") * rate.sqrt(),
        accel_sigma: yaml_number(&imu_yaml, "accelerometer_noise_density") * rate.sqrt(),
        gyro_walk: yaml_number(&imu_yaml, "gyroscope_random_walk"),
        accel_walk: yaml_number(&imu_yaml, "accelerometer_random_walk"),
    }
}

/// Undistorted normalised observations per frame, each with its pixel noise propagated
/// through the undistortion, as the host does (`pixel_to_normalised`): towards the image's
/// corners the lens compresses the view (k1 = −0.28), so one pixel there spans a larger
/// normalised distance: up to twice the centre's in the views around the gap.
fn undistort(frames: &[Frame], cam: &Camera) -> Vec<Undistorted> {
    let pixel_sigma = 1.0;
    let cov_px = Matrix2::identity() * (pixel_sigma * pixel_sigma);
    frames
        .iter()
        .map(|f| {
            let (obs, covs) = f
                .obs
                .iter()
                .filter_map(|(px, g)| {
                    let (n, cov) = pixel_to_normalised(cam, *px, &cov_px).ok()?;
                    Some(((n, *g), cov))
                })
                .unzip();
            (f.t_ns, obs, covs)
        })
        .collect()
}

/// World frame: the grid rotated so that z is up, from the mean specific force of the first
/// `still` samples (the sensor rests there) and the grid pose of the first frame after them.
/// Returns the grid → world rotation and the sensor's initial pose in the world.
fn world_frame(
    imu: &[Imu],
    frames: &[Undistorted],
    rig: &Rig,
    still: usize,
) -> (Matrix3<f64>, Init) {
    let mean_f: Vector3<f64> =
        imu[..still].iter().map(|s| s.accel).sum::<Vector3<f64>>() / still as f64;
    let t_start = imu[still - 1].t_ns;
    let (_, first, _) = frames
        .iter()
        .find(|(t, o, _)| *t >= t_start && o.len() >= 12)
        .expect("a frame with the grid in view");
    let (r_cg, t_cg) = planar_pose(first);
    let up_g: Vector3<f64> = r_cg.transpose() * (rig.r_cs * mean_f.normalize());
    let x_g = (Vector3::x() - up_g * up_g.x).normalize();
    let r_wg = Matrix3::from_rows(&[
        x_g.transpose(),
        up_g.cross(&x_g).transpose(),
        up_g.transpose(),
    ]);
    let r_cw = r_cg * r_wg.transpose();
    let c_w = r_wg * (-r_cg.transpose() * t_cg);
    let r_sw = rig.r_cs.transpose() * r_cw;
    let s_w = c_w - r_sw.transpose() * rig.c_s;
    let q_sw = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r_sw));
    let qv = q_sw.quaternion();
    let init = Init {
        position: [s_w[0] as f32, s_w[1] as f32, s_w[2] as f32],
        attitude: InitAttitude::Full([qv.w as f32, qv.i as f32, qv.j as f32, qv.k as f32]),
    };
    (r_wg, init)
}

/// The configuration of `model` for the rig, its noises from the IMU's and from hand-held
/// motion, still for the first `still` samples.
fn config(model: ModelKind, rig: &Rig, still: usize) -> Config {
    let rate = IMU_RATE;
    let mut cfg = protocol::samples::config();
    cfg.model = model;
    cfg.imu_rate_hz = rate as f32;
    let camera_rate: f64 = 20.0;
    cfg.camera_rate_hz = camera_rate as f32;
    let q = rig.q_cs.quaternion();
    let c_s = rig.c_s;
    cfg.hand_eye = protocol::HandEye {
        q_cs: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
        c_s: [c_s[0] as f32, c_s[1] as f32, c_s[2] as f32],
    };
    cfg.noise.gyro_meas = (rig.gyro_sigma * 2.0) as f32;
    cfg.noise.gyro_bias_walk = (rig.gyro_walk * 5.0) as f32;
    cfg.noise.accel_bias_walk = (rig.accel_walk * 2.0) as f32;
    // Angular acceleration, observed by the gyro every IMU period.
    cfg.noise.angular = (HAND_ANGULAR_ACCEL * (1.0 / rate).sqrt()) as f32;
    // The constant-velocity models observe velocity only through vision, every camera period.
    let cv_motion = (HAND_ACCEL * (1.0 / camera_rate).sqrt()) as f32;
    (cfg.noise.motion, cfg.noise.accel_meas) = match model {
        ModelKind::Acc => (60.0, (rig.accel_sigma * 3.0) as f32),
        ModelKind::Gravity => (cv_motion, 2.0),
        ModelKind::Gyro => (cv_motion, 1.0),
        ModelKind::Vision => unreachable!("the real-data test runs the inertial models"),
    };
    cfg.gate = 25.0;
    // Re-initialisation restarts from the last good position while the hand-held rig keeps
    // moving: the initial uncertainty must cover a second of hand motion.
    cfg.init_sigma.position = 0.3;
    cfg.init_sigma.velocity = 1.0;
    cfg.init_sigma.acceleration = 5.0;
    cfg.divergence.covariance_frobenius = 1e4;
    cfg.divergence.residual_threshold = 50.0;
    cfg.still_samples = still as u16;
    cfg.state_every = 0;
    cfg
}

/// Sends `m` to the device, its answers appended to `answers`.
fn handle(dev: &mut Device<f32>, m: &HostToCore, answers: &mut Vec<CoreToHost>) {
    dev.handle(m, &mut |a| answers.push(a));
}

/// A device with its session opened: `Hello`, `Configure`, `Init`.
fn open_session(cfg: Config, init: Init) -> Device<f32> {
    let mut dev = Device::<f32>::new();
    let mut answers: Vec<CoreToHost> = Vec::new();
    handle(
        &mut dev,
        &HostToCore::Hello(Hello {
            version: PROTOCOL_VERSION,
        }),
        &mut answers,
    );
    handle(&mut dev, &HostToCore::Configure(cfg), &mut answers);
    handle(&mut dev, &HostToCore::Init(init), &mut answers);
    dev
}

/// What a session gave: the prediction errors [px], the correspondences accepted and
/// rejected, the divergences (time [s], reason) and the largest covariance norm.
#[derive(Default)]
struct Tally {
    errs: Vec<f64>,
    accepted: usize,
    rejected: usize,
    divergences: Vec<(f64, protocol::StatusReason)>,
    max_cov: f32,
}

impl Tally {
    /// Notes a divergence that `a` reports; false when it is no such status.
    fn divergence(&mut self, a: &CoreToHost) -> bool {
        match a {
            CoreToHost::Status(st) if st.mode == Mode::Diverged => {
                self.divergences.push((st.t_us as f64 * 1e-6, st.reason));
                true
            }
            _ => false,
        }
    }
}

/// The correspondences of a frame's observations (at most a frame's worth), the grid points
/// in the world by `r_wg`; the error of `p`'s prediction of each point in front of the camera
/// [px, focal length `fx`] goes to `errs`.
fn correspondences(
    p: &protocol::PosePrediction,
    obs: &Observations,
    covs: &[Matrix2<f64>],
    r_wg: &Matrix3<f64>,
    fx: f64,
    errs: &mut Vec<f64>,
) -> Vec<Correspondence> {
    let q_cw = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        p.q_cw[0] as f64,
        p.q_cw[1] as f64,
        p.q_cw[2] as f64,
        p.q_cw[3] as f64,
    ));
    let pc_w = Vector3::new(p.c_w[0] as f64, p.c_w[1] as f64, p.c_w[2] as f64);
    obs.iter()
        .zip(covs)
        .take(protocol::MAX_CORRESPONDENCES_PER_FRAME)
        .map(|((n, g), cov)| {
            let m_w = r_wg * g;
            let pc = q_cw * (m_w - pc_w);
            if pc.z > 0.0 {
                errs.push((Vector2::new(pc.x / pc.z, pc.y / pc.z) - n).norm() * fx);
            }
            Correspondence {
                m_n: [n[0] as f32, n[1] as f32],
                cov_n: [cov[(0, 0)] as f32, cov[(0, 1)] as f32, cov[(1, 1)] as f32],
                m_w: [m_w[0] as f32, m_w[1] as f32, m_w[2] as f32],
                cov_w: [1e-8, 0.0, 0.0, 1e-8, 0.0, 1e-8],
            }
        })
        .collect()
}

/// Sends the correspondences of the frame `p` predicted, in parts, and tallies the answers.
fn apply(
    dev: &mut Device<f32>,
    p: &protocol::PosePrediction,
    corrs: &[Correspondence],
    answers: &mut Vec<CoreToHost>,
    tally: &mut Tally,
) {
    for part in Correspondences::split(p.frame_id, p.t_us, corrs).unwrap() {
        answers.clear();
        handle(dev, &HostToCore::Correspondences(part), answers);
        for a in answers.drain(..) {
            if let CoreToHost::UpdateReport(r) = a {
                tally.accepted += r.accepted as usize;
                tally.rejected += r.rejected as usize;
            } else {
                tally.divergence(&a);
            }
        }
    }
}

/// Feeds every IMU sample to `dev`, triggering on the sample nearest each frame, and applies
/// each frame's correspondences `latency` samples after its trigger.
fn run_session(
    dev: &mut Device<f32>,
    imu: &[Imu],
    frames: &[Undistorted],
    latency: usize,
    r_wg: &Matrix3<f64>,
    fx: f64,
) -> Tally {
    let mut answers: Vec<CoreToHost> = Vec::new();
    let mut pending: Vec<(usize, protocol::PosePrediction, usize)> = Vec::new();
    let mut tally = Tally::default();
    let mut next_frame = 0;
    for (k, s) in imu.iter().enumerate() {
        // Trigger on the sample nearest a camera frame (same clock, within half a period).
        while next_frame < frames.len() && frames[next_frame].0 < s.t_ns - 2_500_000 {
            next_frame += 1;
        }
        let trigger =
            next_frame < frames.len() && (frames[next_frame].0 - s.t_ns).abs() <= 2_500_000;
        let f = |v: Vector3<f64>| [v[0] as f32, v[1] as f32, v[2] as f32];
        let msg = HostToCore::Imu(ImuSample {
            t_us: ((s.t_ns - imu[0].t_ns) / 1000) as u64,
            gyro: f(s.gyro),
            accel: f(s.accel),
            trigger,
        });
        answers.clear();
        handle(dev, &msg, &mut answers);
        for a in answers.drain(..) {
            match a {
                CoreToHost::PosePrediction(p) if trigger => {
                    pending.push((k + latency, p, next_frame))
                }
                a => {
                    tally.divergence(&a);
                }
            }
        }
        if trigger {
            next_frame += 1;
        }
        tally.max_cov = tally.max_cov.max(dev.filter().st.cov_frobenius());
        let due: Vec<_> = pending.iter().filter(|p| p.0 <= k).cloned().collect();
        pending.retain(|p| p.0 > k);
        for (_, p, fi) in due {
            let (_, obs, covs) = &frames[fi];
            if obs.is_empty() {
                continue;
            }
            let corrs = correspondences(&p, obs, covs, r_wg, fx, &mut tally.errs);
            apply(dev, &p, &corrs, &mut answers, &mut tally);
        }
    }
    tally
}

/// Runs `model` with the correspondences of each frame applied `latency` IMU samples (5 ms
/// each) after its trigger.
fn run_model(model: ModelKind, latency: usize, dir: &Path, imu: &[Imu], frames: &[Frame]) -> Row {
    let rig = read_rig(dir);
    let fx = rig.cam.pinhole.fx;
    let frames = undistort(frames, &rig.cam);
    let still = 40;
    let (r_wg, init) = world_frame(imu, &frames, &rig, still);
    let cfg = config(model, &rig, still);
    let mut dev = open_session(cfg, init);
    let mut tally = run_session(&mut dev, imu, &frames, latency, &r_wg, fx);
    let frames_used = tally.errs.len();
    let mean_px = tally.errs.iter().sum::<f64>() / tally.errs.len().max(1) as f64;
    Row {
        model,
        latency_ms: (latency * 5) as u32,
        max_cov: tally.max_cov,
        mean_px,
        median_px: median(&mut tally.errs),
        gated: tally.rejected as f64 / (tally.accepted + tally.rejected).max(1) as f64,
        frames: frames_used,
        divergences: tally.divergences,
    }
}

#[test]
fn real_imu_and_real_correspondences_per_model() {
    let Some(dir) = data_dir() else {
        println!("SKIPPED: ../shared/data/euroc-imu-april is absent (real-data test not run)");
        return;
    };
    let imu = read_imu(&dir.join("imu0.csv"));
    let frames = read_frames(&dir.join("cam1"));
    println!(
        "euroc imu_april: {} IMU samples ({:.1} s), {} frames",
        imu.len(),
        (imu.last().unwrap().t_ns - imu[0].t_ns) as f64 * 1e-9,
        frames.len()
    );
    let mut rows: Vec<Row> = Vec::new();
    for latency in [1, 10] {
        for &m in &ModelKind::INERTIAL {
            rows.push(run_model(m, latency, &dir, &imu, &frames));
        }
    }
    println!(
        "| model | latency | mean prediction error [px] | median [px] | rejected (gate, behind camera) | correspondences | divergences |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for r in &rows {
        println!(
            "| {} | {} ms | {:.3} | {:.2} | {:.2}% | {} | {} |",
            r.model.name(),
            r.latency_ms,
            r.mean_px,
            r.median_px,
            r.gated * 100.0,
            r.frames,
            r.divergences.len()
        );
    }
    for r in &rows {
        println!(
            "{} {} ms: largest ‖P‖_F {:.2}, divergences {:?}",
            r.model.name(),
            r.latency_ms,
            r.max_cov,
            r.divergences
        );
        assert!(
            r.frames > 100_000,
            "{:?} {} ms used too few correspondences",
            r.model,
            r.latency_ms
        );
        assert!(
            r.median_px < 5.0,
            "{:?} {} ms: median {} px",
            r.model,
            r.latency_ms,
            r.median_px
        );
        assert!(
            r.gated < 0.05,
            "{:?} {} ms: {:.1}% rejected",
            r.model,
            r.latency_ms,
            r.gated * 100.0
        );
        // Dead reckoning through the gap, then the predictions snap on again.
        assert!(
            r.divergences.is_empty(),
            "{:?} {} ms: {:?}",
            r.model,
            r.latency_ms,
            r.divergences
        );
    }
    for (latency_ms, acc_bound) in [(5, 0.8), (50, 1.3)] {
        let mean = |m: ModelKind| {
            rows.iter()
                .find(|r| r.model == m && r.latency_ms == latency_ms)
                .expect("row")
                .mean_px
        };
        let (gyro, gravity, acc) = (
            mean(ModelKind::Gyro),
            mean(ModelKind::Gravity),
            mean(ModelKind::Acc),
        );
        assert!(acc <= acc_bound, "acc {latency_ms} ms: mean {acc} px");
        // The paper's finding on real data: the acc model predicts best.
        assert!(
            acc < gravity && acc < gyro,
            "{latency_ms} ms: acc {acc}, gravity {gravity}, gyro {gyro}"
        );
        // With the angular noise of hand motion, the ADIS16448's gyro carries the attitude from
        // frame to frame far better than the accelerometer's tilt, whose noise in the gravity
        // model is the free acceleration (2 m/s²): the gravity model ties with the gyro model
        // (0.1 % apart here), it is not better (issue 18 asked for better: see
        // docs/notes/issue18-robustness.md). Trusting the accelerometer more only makes it worse.
        assert!(
            (gravity - gyro).abs() <= 0.01 * gyro,
            "{latency_ms} ms: gravity {gravity}, gyro {gyro}"
        );
    }
}
