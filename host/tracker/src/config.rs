//! The core's configuration for a rig and a model: IMU rate and noise and the camera's mount
//! from the rig ([`crate::rig::Rig`]), and the process noise tuned per model as the paper did
//! (the constant-velocity models need a much larger motion noise than the acc model).

use protocol::{Capacities, Config, DivergenceParams, InitSigma, ModelKind, NoiseParams, validate};

use crate::error::TrackerError;

use crate::rig::{HandEye, Rig};

/// Tuning knobs of the core (the rest follows from the dataset).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoreTuning {
    /// Peak free acceleration expected [m/s²]: scales the motion noise.
    pub expected_accel: f64,
    /// Angular-acceleration noise density [rad/s²/√Hz]: how fast ω may change between gyro
    /// samples (hand-held shakes reach 150 rad/s²).
    pub angular_noise: f64,
    /// Floor of the accelerometer measurement noise [m/s²] (vibration, misalignment).
    pub accel_noise_floor: f64,
    /// Accelerometer measurement noise [m/s²] instead of the model's default.
    pub accel_noise: Option<f64>,
    /// Outlier gate on `s_i` (eq. 17).
    pub gate: f64,
    /// Initial position standard deviation [m].
    pub init_position_sigma: f64,
    /// Seconds of IMU averaged for roll and pitch at (re)initialisation.
    pub still_seconds: f64,
}

impl Default for CoreTuning {
    fn default() -> Self {
        Self {
            expected_accel: 10.0,
            angular_noise: 10.0,
            accel_noise_floor: 0.3,
            accel_noise: None,
            gate: 30.0,
            init_position_sigma: 0.02,
            still_seconds: 0.3,
        }
    }
}

/// The `Configure` message for `model` on `rig`, named `session` (non-zero: the host's id
/// of this run, which the core reports back in every `HelloAck`).
pub fn core_config(rig: &Rig, model: ModelKind, tuning: &CoreTuning, session: u32) -> Config {
    let rate = rig.imu_rate_hz;
    let noise = rig.imu_noise;
    let (gyro_density, accel_density, gyro_walk, accel_walk) = match noise {
        Some(n) => (
            n.gyroscope_noise_density,
            n.accelerometer_noise_density,
            n.gyroscope_random_walk,
            n.accelerometer_random_walk,
        ),
        // EuRoC's ADIS16448 figures: a middle-of-the-road MEMS IMU.
        None => (1.7e-4, 2.0e-3, 1.9e-5, 3.0e-3),
    };
    let accel = tuning.expected_accel.max(0.5);
    let accel_sample = accel_density * rate.sqrt() * 1.5;
    let camera_rate = rig
        .camera_rate_hz
        .filter(|r| r.is_finite() && *r > 0.0)
        .unwrap_or(20.0);
    let constant_velocity = (accel * 1.5).max(0.5);
    let motion = match model {
        // White jerk: the peak jerk of hand-held motion is about a · 2πf at 1-2 Hz.
        ModelKind::Acc => (accel * 8.0).max(1.0),
        // Vision only: the velocity changes by what the peak acceleration gives over one push
        // (`a · τ`), which white acceleration of density `q` gives over `τ` as `q √τ`; so
        // `q = a √τ`, the angular noise's rule (`OBJECT_IN_HAND_ANGULAR_NOISE`). Nothing but the
        // correspondences corrects the prediction, and a larger `q` lets the velocity follow
        // their noise: where one face seen nearly face on pins the tilt down poorly, the pose
        // then swung 1-3 cm a frame along it while the cube stood still (issue 33).
        ModelKind::Vision => (accel * PUSH_SECONDS.sqrt()).max(0.5),
        // White acceleration for the inertial constant-velocity models, whose gyro (and
        // accelerometer) updates pin the motion down between frames.
        _ => constant_velocity,
    };
    // The room the covariance gets before the monitor calls it diverged is the constant-velocity
    // rule's for the vision-only model too: its angular noise, not its motion noise, grows the
    // covariance while the model is hidden, and a hidden object comes back by itself within
    // seconds (the cube video's hand, 18.4-21.0 s).
    let room = if model == ModelKind::Vision {
        constant_velocity
    } else {
        motion
    };
    let init_sigma = InitSigma {
        position: tuning.init_position_sigma as f32,
        velocity: 0.05,
        acceleration: 0.5,
        tilt: 0.03,
        yaw: 0.05,
        angular_velocity: 0.1,
        gyro_bias: 0.01,
        accel_bias: 0.1,
    };
    // Dead reckoning with a large motion noise grows the covariance fast: leave room for a few
    // frames without vision, and stay at twice the floor the core validates (a multiple of the
    // initial covariance's norm, which a large --init-position-sigma raises).
    let initial = f64::from(validate::initial_covariance_frobenius_sq(
        model,
        &init_sigma,
    ))
    .sqrt();
    let covariance_threshold = (2.0 * room * room)
        .max(10.0)
        .max(2.0 * f64::from(validate::COVARIANCE_THRESHOLD_MARGIN) * initial);
    Config {
        model,
        noise: NoiseParams {
            motion: motion as f32,
            angular: tuning.angular_noise as f32,
            gyro_bias_walk: (gyro_walk * 5.0) as f32,
            accel_bias_walk: (accel_walk * 5.0) as f32,
            gyro_meas: (gyro_density * rate.sqrt() * 1.5).max(2e-3) as f32,
            accel_meas: tuning.accel_noise.unwrap_or(match model {
                // The gravity model's accelerometer noise absorbs the free acceleration. That
                // "noise" is slow (the motion's own frequencies, ~1 s), not white: weighted as
                // white at its size it drags the tilt along with every acceleration. Its white
                // equivalent at 100 Hz is about rms · √(τ f), several times the peak. Measured
                // on desktop-slow with two features (tilt error over the last 3-5 s of 30,
                // seeds 0/1/2): 1.5 m/s² gave 2.6/3.9/4.3°, 3× the peak (2.9 m/s²)
                // 0.8/1.4/1.7°, 6× the peak 0.25/0.45/0.61°, the gyro model 2.2/0.7/2.0°.
                ModelKind::Gravity => (accel * 6.0).max(1.0),
                _ => accel_sample.max(tuning.accel_noise_floor),
            }) as f32,
        },
        init_sigma,
        hand_eye: rig.hand_eye.to_wire(),
        gate: tuning.gate as f32,
        divergence: DivergenceParams {
            // Per camera frame: two frames of nothing but outliers fire the residual test, one
            // never does, and so does a third of the correspondences gated for a while.
            residual_lowpass: 0.8,
            residual_threshold: 50.0,
            covariance_frobenius: covariance_threshold as f32,
            quaternion_norm: 0.01,
        },
        imu_rate_hz: rate as f32,
        camera_rate_hz: camera_rate as f32,
        still_samples: ((rate * tuning.still_seconds).round() as u16).max(2),
        state_every: 1,
        session,
    }
}

/// How long a hand's push or turn accelerates one way [s]: a quarter turn in half a second
/// accelerates for about a quarter of a second.
pub const PUSH_SECONDS: f64 = 0.25;

/// Peak acceleration [m/s²] of the camera relative to an object held and turned in a hand, the
/// default for a video or image folder: a hand turns an object at up to about 12 rad/s² (a
/// quarter turn in half a second), which, seen from 0.4 m, moves the camera in the object's
/// frame at about 5 m/s²; a push across a desk is slower (1-2 m/s²).
pub const OBJECT_IN_HAND_ACCEL: f64 = 5.0;

/// Angular-acceleration noise density [rad/s²/√Hz] of an object turned by hand: about
/// 12 rad/s² held for about a quarter of a second, `12 · √0.25`.
pub const OBJECT_IN_HAND_ANGULAR_NOISE: f64 = 6.0;

/// The `Configure` message of the vision-only model for a camera at `camera_rate_hz`: the
/// constant-velocity motion noise of one push (white acceleration of `a √τ`, with `a` the
/// expected peak acceleration and `τ` [`PUSH_SECONDS`]; white angular acceleration as tuned), no mount (the
/// camera is the sensor), and the clock of its ticks: one at each frame and one just after it,
/// so twice the frame rate.
pub fn vision_config(camera_rate_hz: f64, tuning: &CoreTuning, session: u32) -> Config {
    // The camera is the sensor, and its ticks are the clock.
    let rig = Rig {
        imu_rate_hz: 2.0 * camera_rate_hz,
        imu_noise: None,
        camera_rate_hz: Some(camera_rate_hz),
        hand_eye: HandEye::IDENTITY,
    };
    let mut c = core_config(&rig, ModelKind::Vision, tuning, session);
    c.noise.gyro_meas = 0.0;
    c.noise.accel_meas = 0.0;
    c.noise.gyro_bias_walk = 0.0;
    c.noise.accel_bias_walk = 0.0;
    c.still_samples = 1;
    c.state_every = 1;
    c
}

/// Checks the correspondences' latency against what the core advertised in `HelloAck`: it
/// keeps a frame's snapshot only so long, and refuses later correspondences as too old.
pub fn check_latency(
    latency_s: f64,
    caps: &Capacities,
    config: &Config,
) -> Result<(), TrackerError> {
    let limit_us = caps.max_latency_us(config.imu_rate_hz, config.camera_rate_hz);
    if latency_s * 1e6 > limit_us as f64 {
        return Err(TrackerError::LatencyTooLong {
            latency_s,
            limit_s: limit_us as f64 * 1e-6,
            imu_rate_hz: config.imu_rate_hz,
            camera_rate_hz: config.camera_rate_hz,
            frames: caps.max_pending_frames,
            samples: caps.delay_buffer_samples,
        });
    }
    Ok(())
}
