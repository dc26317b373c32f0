//! The paper's test cases (paper §5) as simulation scenarios: trajectory with exact ground truth,
//! scene description, IMU and camera options; and the EuRoC/ASL writers ([`euroc`]).
//!
//! | scenario | motion | scene |
//! |---|---|---|
//! | `desktop-slow` | robot arm, figure eight, ~1 m/s² | two-sided 20 cm target at 40–60 cm |
//! | `desktop-fast` | same eight, ~10 m/s², ~3 rad/s, arm vibration on the accelerometer | same |
//! | `room` | hand-held walk in a 5 × 4 m room: two 360° turns, a close approach, shakes up to 12.9 m/s² and 9.6 rad/s, an occluder crossing, lighting changes | three modelled walls, a fourth unmodelled |
//! | `foyer` | standing, off-centre hand-held rotations (lever arm), stretches ≤ 0.5 s looking away from the model | 4.5 × 8.5 m wall 7 m away |
//!
//! The scene (textures included) is fixed per scenario; the run seed drives the sensor noise,
//! the initial biases and the vibration phases.

pub mod euroc;
pub mod path;
pub mod scene;

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal, Uniform};

pub use path::{Path, PathState, Peaks, Signal};
pub use scene::{LightState, Lighting, Occluder, Quad, Scene, Surface, vertical_quad};

use super::camera::{Mount, Pinhole};
use super::imu::{ImuNoise, ImuReading, ImuSim};
use super::trajectory::{Kinematics, Ramp, Sines, Trajectory};

/// The scenarios.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ScenarioName {
    /// Robot arm, slow figure eight in front of the desktop target.
    DesktopSlow,
    /// Robot arm, fast figure eight with vibration.
    DesktopFast,
    /// Hand-held walk in a room with three modelled walls.
    Room,
    /// Hand-held off-centre rotations facing a large wall 7 m away.
    Foyer,
}

impl ScenarioName {
    /// All scenarios.
    pub const ALL: [ScenarioName; 4] = [
        ScenarioName::DesktopSlow,
        ScenarioName::DesktopFast,
        ScenarioName::Room,
        ScenarioName::Foyer,
    ];

    /// The command-line name (`desktop-slow`, …).
    pub fn as_str(&self) -> &'static str {
        match self {
            ScenarioName::DesktopSlow => "desktop-slow",
            ScenarioName::DesktopFast => "desktop-fast",
            ScenarioName::Room => "room",
            ScenarioName::Foyer => "foyer",
        }
    }
}

impl ScenarioName {
    /// What the scenario is, in a line (for help texts).
    pub fn describe(&self) -> &'static str {
        match self {
            ScenarioName::DesktopSlow => {
                "Robot arm, slow figure eight in front of the desktop target"
            }
            ScenarioName::DesktopFast => "Robot arm, fast figure eight with vibration",
            ScenarioName::Room => "Hand-held walk in a room with three modelled walls",
            ScenarioName::Foyer => "Hand-held off-centre rotations facing a large wall 7 m away",
        }
    }
}

impl std::str::FromStr for ScenarioName {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|n| n.as_str() == s)
            .ok_or_else(|| {
                let names: Vec<_> = Self::ALL.iter().map(|n| n.as_str()).collect();
                format!(
                    "unknown scenario `{s}`: expected one of {}",
                    names.join(", ")
                )
            })
    }
}

impl std::fmt::Display for ScenarioName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Accelerometer disturbance from the robot arm's mechanical resonances: three sines per
/// axis with seed-drawn phases, scaled up with the speed (the arm only shakes while moving).
/// It is *not* part of the ground truth (the robot's reported trajectory does not show it).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Vibration {
    /// RMS per axis at full strength [m/s²].
    pub rms: f64,
    /// Resonance frequencies [Hz] (keep them below half the IMU rate).
    pub frequencies: [f64; 3],
    /// Speed at and above which the vibration is at full strength [m/s].
    pub full_at_speed: f64,
}

/// Measurement ranges; readings are clipped to ±range per axis.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Saturation {
    /// Gyro range [rad/s].
    pub gyro: f64,
    /// Accelerometer range [m/s²].
    pub accel: f64,
}

impl Saturation {
    /// An MT9-class range: ±900 °/s and ±50 m/s² (the ±5 g variant).
    pub const MT9: Saturation = Saturation {
        gyro: 900.0 * PI / 180.0,
        accel: 50.0,
    };
}

/// IMU options of a scenario.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuOptions {
    /// Sample rate [Hz].
    pub rate_hz: f64,
    /// White noise and bias random walk densities.
    pub noise: ImuNoise,
    /// Standard deviations of the constant initial biases, drawn from the seed:
    /// `(gyro [rad/s], accel [m/s²])`.
    pub initial_bias_sigma: (f64, f64),
    /// Arm vibration on the accelerometer.
    pub vibration: Option<Vibration>,
    /// Clipping.
    pub saturation: Option<Saturation>,
}

impl ImuOptions {
    /// An MT9-class IMU at 100 Hz.
    pub fn mt9() -> Self {
        ImuOptions {
            rate_hz: 100.0,
            noise: ImuNoise::MT9,
            initial_bias_sigma: (0.005, 0.05),
            vibration: None,
            saturation: Some(Saturation::MT9),
        }
    }

    /// A perfect IMU: no noise, biases, vibration or clipping.
    pub fn ideal(rate_hz: f64) -> Self {
        ImuOptions {
            rate_hz,
            noise: ImuNoise {
                gyro_density: 0.0,
                accel_density: 0.0,
                gyro_walk: 0.0,
                accel_walk: 0.0,
            },
            initial_bias_sigma: (0.0, 0.0),
            vibration: None,
            saturation: None,
        }
    }

    /// Turns noise, biases, vibration and clipping off, keeping the rate.
    pub fn without_noise(self) -> Self {
        Self::ideal(self.rate_hz)
    }
}

/// The camera of a scenario, for the default 320×240 image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraSpec {
    /// Intrinsics at 320×240.
    pub pinhole: Pinhole,
    /// Radial-tangential distortion `[k1, k2, p1, p2]` (EuRoC order).
    pub distortion: [f64; 4],
    /// Hand-eye mount on the IMU.
    pub mount: Mount,
    /// One frame every `every` IMU samples (the IMU triggers the camera).
    pub every: u32,
    /// Exposure time [s], centred on the trigger time.
    pub exposure: f64,
}

impl CameraSpec {
    /// The paper's camera: 320×240, 60° horizontal field of view, a moderate barrel
    /// distortion, looking along the IMU's x axis, triggered every 4th IMU sample.
    pub fn paper() -> Self {
        // Camera z = body x, camera x = −body y, camera y = −body z, then a small
        // misalignment so the hand-eye rotation is not a pure axis permutation.
        let axes = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
            0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0,
        ));
        let tilt = UnitQuaternion::from_euler_angles(0.012, -0.02, 0.008);
        CameraSpec {
            pinhole: Pinhole {
                fx: 277.0,
                fy: 277.5,
                cx: 161.2,
                cy: 118.7,
                width: 320,
                height: 240,
            },
            distortion: [-0.21, 0.045, 4.0e-4, -2.5e-4],
            mount: Mount {
                q_cs: tilt * UnitQuaternion::from_rotation_matrix(&axes),
                c_s: Vector3::new(0.025, -0.012, 0.018),
            },
            every: 4,
            exposure: 0.008,
        }
    }

    /// Intrinsics for a `width × height` image with the same horizontal field of view and
    /// the same relative principal point.
    pub fn pinhole_for(&self, width: u32, height: u32) -> Pinhole {
        let p = &self.pinhole;
        let s = width as f64 / p.width as f64;
        let sv = height as f64 / p.height as f64;
        Pinhole {
            fx: p.fx * s,
            fy: p.fy * s,
            cx: (p.cx + 0.5) * s - 0.5,
            cy: (p.cy + 0.5) * sv - 0.5,
            width,
            height,
        }
    }
}

/// A complete scenario.
#[derive(Clone, Debug, PartialEq)]
pub struct Scenario {
    /// Which one.
    pub name: ScenarioName,
    /// Trajectory of the IMU with exact ground truth.
    pub path: Path,
    /// What the camera sees.
    pub scene: Scene,
    /// IMU options.
    pub imu: ImuOptions,
    /// Camera options.
    pub camera: CameraSpec,
}

/// A bad scenario parameter.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScenarioError {
    /// Duration not positive, not finite or too long.
    #[error("duration must be in (0, {max}] s, got {got}")]
    Duration {
        /// Requested.
        got: f64,
        /// Limit.
        max: f64,
    },
    /// IMU rate not usable.
    #[error("IMU rate must be in [10, 10000] Hz, got {0}")]
    Rate(f64),
    /// Camera divider zero.
    #[error("the camera must be triggered every n ≥ 1 IMU samples, got {0}")]
    Every(u32),
}

/// Longest duration accepted [s] (bounds the output size).
pub const MAX_DURATION: f64 = 3600.0;

impl Scenario {
    /// The scenario with its nominal duration and default options.
    pub fn new(name: ScenarioName) -> Self {
        match name {
            ScenarioName::DesktopSlow => desktop(false),
            ScenarioName::DesktopFast => desktop(true),
            ScenarioName::Room => room(),
            ScenarioName::Foyer => foyer(),
        }
    }

    /// Changes the duration (shorter: the beginning of the sequence; longer: the device rests
    /// at the end).
    pub fn with_duration(mut self, seconds: f64) -> Result<Self, ScenarioError> {
        if !(seconds.is_finite() && seconds > 0.0 && seconds <= MAX_DURATION) {
            return Err(ScenarioError::Duration {
                got: seconds,
                max: MAX_DURATION,
            });
        }
        self.path.length = seconds;
        Ok(self)
    }

    /// Changes the IMU rate and the camera divider.
    pub fn with_rates(mut self, imu_hz: f64, every: u32) -> Result<Self, ScenarioError> {
        if !(imu_hz.is_finite() && (10.0..=10000.0).contains(&imu_hz)) {
            return Err(ScenarioError::Rate(imu_hz));
        }
        if every == 0 {
            return Err(ScenarioError::Every(every));
        }
        self.imu.rate_hz = imu_hz;
        self.camera.every = every;
        Ok(self)
    }

    /// Duration [s].
    pub fn duration(&self) -> f64 {
        self.path.length
    }

    /// Number of IMU samples (the first at t = 0, the last at or before the duration).
    pub fn imu_count(&self) -> usize {
        (self.path.length * self.imu.rate_hz + 1e-9).floor() as usize + 1
    }

    /// Time stamp of IMU sample `k` in nanoseconds since the start.
    pub fn imu_ns(&self, k: usize) -> u64 {
        (k as f64 * 1e9 / self.imu.rate_hz).round() as u64
    }

    /// Indices of the IMU samples that trigger a camera frame.
    pub fn camera_samples(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.imu_count()).step_by(self.camera.every as usize)
    }

    /// Camera pose `(c_w, q_cw)` at `t`.
    pub fn camera_pose(&self, t: f64) -> (Vector3<f64>, UnitQuaternion<f64>) {
        self.camera.mount.camera_pose(&self.path.at(t))
    }
}

/// Time stamp of the first sample in the written files [ns] (an arbitrary epoch-like value,
/// as real EuRoC recordings have; simulation time is `(stamp − T0_NS) / 1e9`).
pub const T0_NS: u64 = 1_700_000_000_000_000_000;

/// One IMU sample with the truth behind it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuSample {
    /// Nanoseconds since the start.
    pub ns: u64,
    /// The reading (with the true biases of that instant).
    pub reading: ImuReading,
    /// Ground truth.
    pub truth: Kinematics,
}

/// Simulates the scenario's IMU over its whole duration, deterministically for `seed`.
pub fn simulate_imu(scenario: &Scenario, seed: u64) -> Vec<ImuSample> {
    let o = &scenario.imu;
    let mut rng = StdRng::seed_from_u64(seed ^ 0x1a2b_3c4d_5e6f_7788);
    let mut gauss3 = |s: f64| -> Vector3<f64> {
        Vector3::from_fn(|_, _| {
            let g: f64 = StandardNormal.sample(&mut rng);
            g * s
        })
    };
    let gyro_bias = gauss3(o.initial_bias_sigma.0);
    let accel_bias = gauss3(o.initial_bias_sigma.1);
    let phases: [[f64; 3]; 3] = {
        let mut r = StdRng::seed_from_u64(seed ^ 0x7777_0000_1234_abcd);
        let u = Uniform::new(0.0, TAU).expect("valid range");
        std::array::from_fn(|_| std::array::from_fn(|_| u.sample(&mut r)))
    };
    let mut imu = ImuSim::new(o.noise, o.rate_hz, gyro_bias, accel_bias, seed);
    (0..scenario.imu_count())
        .map(|k| {
            let ns = scenario.imu_ns(k);
            let truth = scenario.path.at(ns as f64 * 1e-9);
            let mut reading = imu.read(&truth);
            if let Some(v) = o.vibration {
                let strength = (truth.v_w.norm() / v.full_at_speed).min(1.0);
                let amp = v.rms * (2.0f64 / 3.0).sqrt() * strength;
                for (axis, ph) in phases.iter().enumerate() {
                    reading.accel[axis] += v
                        .frequencies
                        .iter()
                        .zip(ph)
                        .map(|(f, p)| amp * (TAU * f * truth.t + p).sin())
                        .sum::<f64>();
                }
            }
            if let Some(s) = o.saturation {
                reading.gyro = reading.gyro.map(|x| x.clamp(-s.gyro, s.gyro));
                reading.accel = reading.accel.map(|x| x.clamp(-s.accel, s.accel));
            }
            ImuSample { ns, reading, truth }
        })
        .collect()
}

// ---------------------------------------------------------------------------------------
// The scenarios.

fn always(terms: &[(f64, f64, f64)], from: f64) -> Signal {
    Signal::Sines {
        sines: Sines {
            terms: terms.to_vec(),
        },
        on: Ramp {
            start: from,
            length: 1.0,
        },
        off: Ramp {
            start: f64::INFINITY,
            length: 0.0,
        },
    }
}

fn horizontal_quad(
    name: &str,
    x: (f64, f64),
    y: (f64, f64),
    z: f64,
    facing_up: bool,
    (surface, seed, tpm): (Surface, u64, f64),
) -> Quad {
    let c = |a: f64, b: f64| Vector3::new(a, b, z);
    let corners = if facing_up {
        [c(x.1, y.1), c(x.1, y.0), c(x.0, y.0), c(x.0, y.1)]
    } else {
        [c(x.0, y.1), c(x.0, y.0), c(x.1, y.0), c(x.1, y.1)]
    };
    Quad {
        name: name.into(),
        corners,
        surface,
        texture_seed: seed,
        texels_per_metre: tpm,
    }
}

/// Robot arm: the camera runs a figure eight in a plane 48 cm in front of the target, aimed at
/// its centre, with a wrist roll.
fn desktop(fast: bool) -> Scenario {
    // The eight: y = A sin ωt, z = B sin 2ωt, distance x = C sin(ωt + ½).
    let (f, length) = if fast { (1.03, 30.0) } else { (0.293, 40.0) };
    let (start, fade) = (1.5, 2.0);
    let end = length - 1.5;
    let target = Vector3::new(-0.02, 0.0, 0.1);
    let eight = |terms: &[(f64, f64, f64)]| vec![Signal::burst(terms, start, end, fade)];
    let path = Path {
        centre: Vector3::new(-0.5, 0.0, 0.2),
        position: [
            eight(&[(0.07, f, 0.5)]),
            eight(&[(0.15, f, 0.0)]),
            eight(&[(0.05, 2.0 * f, 0.0)]),
        ],
        look_at: Some(target),
        attitude0: [0.0, 0.0, 0.0],
        attitude: [
            vec![],
            vec![],
            eight(&[(if fast { 0.23 } else { 0.12 }, f, 1.0)]),
        ],
        lever_arm: Vector3::zeros(),
        length,
    };
    // Two 14 × 20 cm faces at 90°, their common edge towards the camera.
    let edge = Vector3::new(-0.07, 0.0, 0.1);
    let d = 0.14 / 2.0f64.sqrt();
    let face = |name: &str, side: f64, seed: u64| {
        vertical_quad(
            name,
            edge + Vector3::new(d / 2.0, side * d / 2.0, 0.0),
            if side < 0.0 { -0.75 * PI } else { 0.75 * PI },
            (0.14, 0.2),
            Surface::Target,
            seed,
            3000.0,
        )
    };
    let scene = Scene {
        modelled: vec![face("target_left", -1.0, 11), face("target_right", 1.0, 12)],
        unmodelled: vec![
            horizontal_quad(
                "desk",
                (-1.0, 0.65),
                (-1.0, 1.0),
                0.0,
                true,
                (Surface::Floor, 13, 500.0),
            ),
            vertical_quad(
                "back_wall",
                Vector3::new(0.7, 0.0, 0.4),
                PI,
                (4.0, 2.6),
                Surface::Wall { posters: 3 },
                14,
                250.0,
            ),
            vertical_quad(
                "shelf",
                Vector3::new(0.45, -0.45, 0.25),
                PI,
                (0.4, 0.5),
                Surface::Clutter,
                15,
                600.0,
            ),
        ],
        occluders: vec![],
        lighting: Lighting {
            gain: vec![always(&[(-0.15, 0.03, 0.0), (0.05, 0.11, 1.0)], 0.0)],
            offset: vec![always(&[(6.0, 0.05, 0.3)], 0.0)],
            gradient_u: vec![always(&[(0.15, 0.02, 0.5)], 0.0)],
            gradient_v: vec![always(&[(-0.1, 0.015, 0.2)], 0.0)],
        },
        clip: (0.05, 10.0),
    };
    let mut imu = ImuOptions::mt9();
    if fast {
        imu.vibration = Some(Vibration {
            rms: 0.35,
            frequencies: [17.3, 28.9, 41.7],
            full_at_speed: 0.2,
        });
    }
    Scenario {
        name: if fast {
            ScenarioName::DesktopFast
        } else {
            ScenarioName::DesktopSlow
        },
        path,
        scene,
        imu,
        camera: CameraSpec::paper(),
    }
}

/// Room 5 × 4 × 2.6 m, x ∈ [0, 5], y ∈ [0, 4]; walls x = 0, y = 0, y = 4 modelled, x = 5 not.
fn room() -> Scenario {
    Scenario {
        name: ScenarioName::Room,
        path: room_path(45.0),
        scene: room_scene(),
        imu: ImuOptions::mt9(),
        camera: CameraSpec::paper(),
    }
}

/// The room's hand-held path of `length` s: tremor, a close approach to the wall x = 0, two
/// 360° turns and fast shakes.
fn room_path(length: f64) -> Path {
    let tremor =
        |a: f64, f1: f64, f2: f64, ph: f64| always(&[(a, f1, ph), (a * 0.6, f2, ph + 1.3)], 1.5);
    Path {
        centre: Vector3::new(3.7, 2.0, 1.5),
        position: [
            vec![
                tremor(0.003, 1.3, 3.1, 0.0),
                // Close approach to the wall x = 0 and back.
                Signal::step(15.0, 4.0, -3.25),
                Signal::step(22.0, 4.0, 3.0),
                Signal::burst(&[(0.3, 0.2, 0.0)], 2.0, 8.0, 1.5),
            ],
            vec![
                tremor(0.004, 1.7, 2.6, 0.5),
                // Fast translational shake.
                Signal::burst(&[(0.0721, 2.0, 0.0)], 31.0, 34.0, 0.5),
                Signal::burst(&[(0.25, 0.25, 0.0)], 2.0, 8.0, 1.5),
            ],
            vec![
                tremor(0.003, 1.1, 2.9, 1.0),
                Signal::burst(&[(0.0243, 2.0, 1.2)], 31.0, 34.0, 0.5),
            ],
        ],
        look_at: None,
        // Facing the modelled wall x = 0.
        attitude0: [PI, -0.05, 0.0],
        attitude: [
            vec![
                tremor(0.01, 0.9, 2.3, 0.2),
                Signal::burst(&[(0.35, 0.15, 0.0)], 2.0, 8.0, 1.5),
                // First 360° turn, in place.
                Signal::step(8.5, 5.5, TAU),
                // Fast rotational shake.
                Signal::burst(&[(0.6, 2.5, 0.0)], 35.0, 38.0, 0.5),
                // Second 360° turn, faster and the other way.
                Signal::step(39.0, 3.0, -TAU),
                Signal::burst(&[(0.4, 0.3, 0.5)], 19.0, 22.0, 1.0),
            ],
            vec![
                tremor(0.008, 1.2, 2.7, 0.9),
                Signal::burst(&[(0.12, 0.2, 0.3)], 2.0, 8.0, 1.5),
                Signal::burst(&[(0.15, 2.5, 1.0)], 35.0, 38.0, 0.5),
            ],
            vec![tremor(0.01, 0.8, 2.1, 0.4)],
        ],
        lever_arm: Vector3::zeros(),
        length,
    }
}

/// A wall of the room: full height (2.6 m), `w` wide, centred at `c`.
fn room_wall(name: &str, c: Vector3<f64>, yaw: f64, w: f64, s: Surface, seed: u64) -> Quad {
    vertical_quad(name, c, yaw, (w, 2.6), s, seed, 400.0)
}

/// The room's surfaces outside the model: the wall x = 5, the floor, the ceiling and a
/// cabinet.
fn room_unmodelled() -> Vec<Quad> {
    vec![
        room_wall(
            "wall_x5",
            Vector3::new(5.0, 2.0, 1.3),
            PI,
            4.0,
            Surface::Wall { posters: 3 },
            24,
        ),
        horizontal_quad(
            "floor",
            (0.0, 5.0),
            (0.0, 4.0),
            0.0,
            true,
            (Surface::Floor, 25, 200.0),
        ),
        horizontal_quad(
            "ceiling",
            (0.0, 5.0),
            (0.0, 4.0),
            2.6,
            false,
            (Surface::Ceiling, 26, 100.0),
        ),
        vertical_quad(
            "cabinet",
            Vector3::new(4.7, 1.0, 0.6),
            PI,
            (1.2, 1.2),
            Surface::Clutter,
            28,
            400.0,
        ),
    ]
}

/// The room: its modelled walls, the rest ([`room_unmodelled`]), a person walking through,
/// and the dimmed lights.
fn room_scene() -> Scene {
    let person = vertical_quad(
        "person",
        Vector3::zeros(),
        0.0,
        (0.55, 1.8),
        Surface::Occluder,
        27,
        300.0,
    );
    Scene {
        modelled: vec![
            room_wall(
                "wall_x0",
                Vector3::new(0.0, 2.0, 1.3),
                0.0,
                4.0,
                Surface::Wall { posters: 4 },
                21,
            ),
            room_wall(
                "wall_y0",
                Vector3::new(2.5, 0.0, 1.3),
                FRAC_PI_2,
                5.0,
                Surface::Wall { posters: 5 },
                22,
            ),
            room_wall(
                "wall_y4",
                Vector3::new(2.5, 4.0, 1.3),
                -FRAC_PI_2,
                5.0,
                Surface::Wall { posters: 5 },
                23,
            ),
        ],
        unmodelled: room_unmodelled(),
        occluders: vec![Occluder {
            quad: person,
            from: Vector3::new(1.4, -0.5, 0.9),
            to: Vector3::new(1.4, 4.5, 0.9),
            start: 27.0,
            duration: 3.5,
        }],
        lighting: Lighting {
            gain: vec![
                always(&[(0.06, 0.04, 0.0)], 0.0),
                // Lights dimmed, then back.
                Signal::step(11.0, 1.0, -0.45),
                Signal::step(24.0, 1.5, 0.45),
            ],
            offset: vec![always(&[(8.0, 0.03, 0.0)], 0.0)],
            gradient_u: vec![Signal::step(28.0, 3.0, 0.4), Signal::step(40.0, 2.0, -0.4)],
            gradient_v: vec![always(&[(0.12, 0.02, 0.0)], 0.0)],
        },
        clip: (0.05, 20.0),
    }
}

/// Foyer: standing on the first floor (eye height 4.2 m), facing the wall x = 7; the device at
/// arm's length swings away from the model and back.
fn foyer() -> Scenario {
    Scenario {
        name: ScenarioName::Foyer,
        path: foyer_path(40.0),
        scene: foyer_scene(),
        imu: ImuOptions::mt9(),
        camera: CameraSpec::paper(),
    }
}

/// The foyer's path of `length` s: the person barely moves while the device at arm's length
/// swings away from the modelled wall and back.
fn foyer_path(length: f64) -> Path {
    // (start, duration of each swing, hold, yaw, pitch)
    let swings: [(f64, f64, f64, f64, f64); 6] = [
        (6.0, 0.55, 0.1, 1.25, 0.0),
        (11.0, 0.5, 0.05, -1.25, 0.0),
        (16.0, 0.6, 0.05, 0.0, -0.85),
        (21.0, 0.5, 0.1, 1.2, -0.3),
        (27.0, 0.45, 0.05, -1.2, 0.2),
        (33.0, 0.5, 0.1, 0.3, 0.9),
    ];
    let mut yaw = vec![
        always(&[(0.2, 0.07, 0.0), (0.05, 0.6, 1.0)], 1.5),
        always(&[(0.006, 1.7, 0.2), (0.004, 3.3, 0.0)], 1.5),
    ];
    let mut pitch = vec![always(&[(0.08, 0.05, 0.5), (0.005, 2.1, 0.0)], 1.5)];
    for (start, dur, hold, dy, dp) in swings {
        if dy != 0.0 {
            yaw.push(Signal::step(start, dur, dy));
            yaw.push(Signal::step(start + dur + hold, dur, -dy));
        }
        if dp != 0.0 {
            pitch.push(Signal::step(start, dur, dp));
            pitch.push(Signal::step(start + dur + hold, dur, -dp));
        }
    }
    Path {
        // The shoulder: the person barely moves.
        centre: Vector3::new(0.0, 0.0, 4.0),
        position: [
            vec![always(&[(0.02, 0.2, 0.0)], 1.5)],
            vec![always(&[(0.05, 0.1, 0.7)], 1.5)],
            vec![always(&[(0.01, 0.3, 0.2)], 1.5)],
        ],
        look_at: None,
        attitude0: [0.0, 0.02, 0.0],
        attitude: [yaw, pitch, vec![always(&[(0.04, 0.13, 0.0)], 1.5)]],
        lever_arm: Vector3::new(0.45, 0.0, 0.2),
        length,
    }
}

/// The foyer's walls around the modelled wall x = 7, its floor, ceiling, side walls and the
/// gallery's parapet, and slowly varying lighting.
fn foyer_scene() -> Scene {
    let wall = |name: &str, y: (f64, f64), z: (f64, f64), s: Surface, seed: u64, tpm: f64| {
        let c = Vector3::new(7.0, (y.0 + y.1) / 2.0, (z.0 + z.1) / 2.0);
        vertical_quad(name, c, PI, (y.1 - y.0, z.1 - z.0), s, seed, tpm)
    };
    let plaster = Surface::Wall { posters: 0 };
    Scene {
        modelled: vec![wall(
            "foyer_wall",
            (-4.25, 4.25),
            (1.75, 6.25),
            Surface::Wall { posters: 9 },
            31,
            200.0,
        )],
        unmodelled: vec![
            wall("wall_left", (-12.0, -4.25), (0.0, 9.0), plaster, 32, 60.0),
            wall("wall_right", (4.25, 12.0), (0.0, 9.0), plaster, 33, 60.0),
            wall("wall_below", (-4.25, 4.25), (0.0, 1.75), plaster, 34, 60.0),
            wall("wall_above", (-4.25, 4.25), (6.25, 9.0), plaster, 35, 60.0),
            horizontal_quad(
                "foyer_floor",
                (-3.0, 7.0),
                (-12.0, 12.0),
                0.0,
                true,
                (Surface::Floor, 36, 60.0),
            ),
            horizontal_quad(
                "foyer_ceiling",
                (-3.0, 7.0),
                (-12.0, 12.0),
                9.0,
                false,
                (Surface::Ceiling, 37, 30.0),
            ),
            vertical_quad(
                "side_wall_left",
                Vector3::new(2.0, -12.0, 4.5),
                FRAC_PI_2,
                (10.0, 9.0),
                Surface::Clutter,
                38,
                60.0,
            ),
            vertical_quad(
                "side_wall_right",
                Vector3::new(2.0, 12.0, 4.5),
                -FRAC_PI_2,
                (10.0, 9.0),
                Surface::Clutter,
                39,
                60.0,
            ),
            // The gallery's parapet in front of the person.
            horizontal_quad(
                "gallery",
                (-3.0, 0.8),
                (-12.0, 12.0),
                3.0,
                true,
                (Surface::Floor, 40, 120.0),
            ),
        ],
        occluders: vec![],
        lighting: Lighting {
            gain: vec![always(&[(0.1, 0.025, 0.0), (0.04, 0.2, 0.3)], 0.0)],
            offset: vec![always(&[(5.0, 0.04, 1.0)], 0.0)],
            gradient_u: vec![always(&[(0.25, 0.01, 0.0)], 0.0)],
            gradient_v: vec![always(&[(0.1, 0.03, 0.0)], 0.0)],
        },
        clip: (0.05, 40.0),
    }
}

#[cfg(test)]
mod tests;
