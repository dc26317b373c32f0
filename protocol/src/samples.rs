//! One representative instance of every message kind: the worked examples of `PROTOCOL.md`
//! (checked byte for byte by a test), the loop-back self-test's traffic, and the size table.

use heapless::Vec;

use crate::error::{DecodeError, ErrorCode, InvalidField};
use crate::messages::*;
use crate::version::{PROTOCOL_VERSION, Version};

/// A typical configuration: acc model, noise close to an XSens MT9-class IMU, hand-eye of a
/// camera looking along the sensor's x axis.
pub const fn config() -> Config {
    Config {
        model: ModelKind::Acc,
        noise: NoiseParams {
            motion: 5.0,
            angular: 2.0,
            gyro_bias_walk: 1e-4,
            accel_bias_walk: 1e-3,
            gyro_meas: 0.01,
            accel_meas: 0.05,
        },
        init_sigma: InitSigma {
            position: 0.05,
            velocity: 0.1,
            acceleration: 1.0,
            tilt: 0.05,
            yaw: 0.5,
            angular_velocity: 0.1,
            gyro_bias: 0.02,
            accel_bias: 0.1,
        },
        hand_eye: HandEye {
            q_cs: [0.5, -0.5, 0.5, -0.5],
            c_s: [0.02, 0.0, -0.01],
        },
        gate: 30.0,
        divergence: DivergenceParams {
            // Per camera frame: two frames of nothing but outliers fire the residual test, one
            // never does, and so does a third of the correspondences gated for a while.
            residual_lowpass: 0.8,
            residual_threshold: 50.0,
            covariance_frobenius: 10.0,
            quaternion_norm: 0.01,
        },
        imu_rate_hz: 100.0,
        camera_rate_hz: 25.0,
        still_samples: 50,
        state_every: 1,
        session: 0x5E55_1011,
    }
}

/// A correspondence with small isotropic covariances.
pub const fn correspondence(m_n: [f32; 2], m_w: [f32; 3]) -> Correspondence {
    Correspondence {
        m_n,
        cov_n: [1e-6, 0.0, 1e-6],
        m_w,
        cov_w: [1e-6, 0.0, 0.0, 1e-6, 0.0, 1e-6],
    }
}

/// A contour correspondence with small isotropic covariances: the contour found at `d` along
/// the unit normal `n`.
pub const fn contour(m_w: [f32; 3], n: [f32; 2], d: f32) -> ContourPoint {
    ContourPoint {
        m_w,
        cov_w: [1e-6, 0.0, 0.0, 1e-6, 0.0, 1e-6],
        n,
        d,
        var_d: 1e-6,
    }
}

/// Named host messages, one per kind (two for `Init`).
pub fn host_messages() -> [(&'static str, HostToCore); 12] {
    let mut items = Vec::new();
    let _ = items.push(correspondence([0.125, -0.25], [0.5, 0.25, 0.0]));
    let _ = items.push(correspondence([-0.0625, 0.5], [0.0, 0.1, 0.2]));
    let mut contours = Vec::new();
    let _ = contours.push(contour([0.5, 0.25, 0.0], [0.6, -0.8], 0.25));
    let _ = contours.push(contour([0.0, 0.1, 0.2], [0.0, 1.0], -0.125));
    [
        (
            "Hello",
            HostToCore::Hello(Hello {
                version: PROTOCOL_VERSION,
            }),
        ),
        ("Configure", HostToCore::Configure(config())),
        (
            "Init (gravity and yaw)",
            HostToCore::Init(Init {
                position: [0.0, -0.5, 1.25],
                attitude: InitAttitude::GravityAndYaw(1.5),
            }),
        ),
        (
            "Init (full orientation)",
            HostToCore::Init(Init {
                position: [1.0, 2.0, 3.0],
                attitude: InitAttitude::Full([1.0, 0.0, 0.0, 0.0]),
            }),
        ),
        (
            "Imu",
            HostToCore::Imu(ImuSample {
                t_us: 1_000_000,
                gyro: [0.01, -0.02, 0.5],
                accel: [0.1, 0.0, 9.81],
                trigger: true,
            }),
        ),
        (
            "Correspondences",
            HostToCore::Correspondences(Correspondences {
                frame_id: 42,
                trigger_us: 1_000_000,
                part: 0,
                parts: 1,
                items,
            }),
        ),
        ("Reset", HostToCore::Reset),
        (
            "Tick",
            HostToCore::Tick(Tick {
                t_us: 1_033_333,
                trigger: true,
            }),
        ),
        ("Query", HostToCore::Query),
        (
            "Resume",
            HostToCore::Resume(Resume {
                t_us: 6_000_000,
                s_w: [0.5, -0.25, 1.0],
                q_sw: [0.0, 1.0, 0.0, 0.0],
                v_w: [0.25, 0.0, -0.125],
                a_w: [0.0; 3],
                omega_s: [0.0, 0.0, 0.5],
                gyro_bias: [0.0; 3],
                accel_bias: [0.0; 3],
            }),
        ),
        (
            "Sampling",
            HostToCore::Sampling(Sampling {
                source: SampleSource::Core { trigger_every: 4 },
                raw_imu: false,
            }),
        ),
        (
            "Contours",
            HostToCore::Contours(Contours {
                frame_id: 42,
                trigger_us: 1_000_000,
                part: 1,
                parts: 2,
                items: contours,
            }),
        ),
    ]
}

/// Named core messages, one per kind (five for `Error`).
pub fn core_messages() -> [(&'static str, CoreToHost); 13] {
    [
        ("HelloAck", hello_ack()),
        (
            "Error (version mismatch)",
            CoreToHost::error(ErrorCode::VersionMismatch {
                core: PROTOCOL_VERSION,
                host: Version { major: 2, minor: 0 },
            }),
        ),
        (
            "Error (invalid field)",
            CoreToHost::error(ErrorCode::Invalid(InvalidField::CorrespondenceCovariance {
                index: 3,
            })),
        ),
        (
            "Error (decode)",
            CoreToHost::error(ErrorCode::Decode(DecodeError::Crc)),
        ),
        (
            "Error (IMU sample in the vision-only model)",
            CoreToHost::error(ErrorCode::ImuInVisionModel),
        ),
        ("PosePrediction", pose_prediction()),
        ("State", state_report()),
        ("UpdateReport", update_report()),
        (
            "Status",
            CoreToHost::Status(Status {
                t_us: 1_010_000,
                mode: Mode::DeadReckoning,
                reason: StatusReason::NoVision,
            }),
        ),
        (
            "Error (timestamp)",
            CoreToHost::error(ErrorCode::TimestampNotIncreasing {
                last_us: 1_010_000,
                got_us: 1_000_000,
            }),
        ),
        (
            "Trigger",
            CoreToHost::Trigger(Trigger {
                frame_id: 7,
                t_us: 1_040_000,
            }),
        ),
        (
            "RawImu",
            CoreToHost::RawImu(ImuSample {
                t_us: 1_000_000,
                gyro: [0.01, -0.02, 0.5],
                accel: [0.1, 0.0, 9.81],
                trigger: true,
            }),
        ),
        ("Sampling (gap)", sampling_gap()),
    ]
}

/// The core's answer to `Hello`: this protocol version, the acc model, the limits of this
/// crate and those of a small core.
fn hello_ack() -> CoreToHost {
    CoreToHost::HelloAck(HelloAck {
        version: PROTOCOL_VERSION,
        model: Some(ModelKind::Acc),
        capacities: Capacities {
            max_frame_len: crate::MAX_FRAME_LEN as u16,
            max_correspondences_per_message: crate::MAX_CORRESPONDENCES_PER_MESSAGE as u16,
            max_correspondences_per_frame: 64,
            delay_buffer_samples: 32,
            max_pending_frames: 4,
            scalar_bits: 32,
        },
        session: 0x5E55_1011,
    })
}

/// A pose prediction for frame 42, with a diagonal covariance (position σ 1 cm, rotation
/// about 3 mrad).
fn pose_prediction() -> CoreToHost {
    let mut cov = [0.0f32; 21];
    for i in 0..6 {
        cov[sym_index(6, i, i)] = if i < 3 { 1e-4 } else { 1e-5 };
    }
    CoreToHost::PosePrediction(PosePrediction {
        frame_id: 42,
        t_us: 1_000_000,
        c_w: [0.0, -0.5, 1.25],
        q_cw: [0.5, -0.5, 0.5, -0.5],
        cov,
    })
}

/// A state report while tracking, with a diagonal camera-pose covariance.
fn state_report() -> CoreToHost {
    CoreToHost::State(StateReport {
        t_us: 1_010_000,
        s_w: [0.0, -0.5, 1.25],
        q_sw: [1.0, 0.0, 0.0, 0.0],
        v_w: [0.1, 0.0, 0.0],
        a_w: [0.0, 0.0, 0.0],
        omega_s: [0.0, 0.0, 0.5],
        gyro_bias: [0.001, -0.002, 0.0],
        accel_bias: [0.0, 0.0, 0.01],
        health: Health {
            mode: Mode::Tracking,
            covariance_frobenius: 0.25,
            residual_lowpass: 1.5,
            quaternion_norm_error: 1e-6,
        },
        cov: {
            let mut c = [0.0; 21];
            for (i, v) in [1e-4, 1e-4, 4e-4, 3e-5, 3e-5, 1e-4].into_iter().enumerate() {
                c[crate::sym_index(6, i, i)] = v;
            }
            c
        },
    })
}

/// The report on frame 42's first part: two correspondences accepted, one (the large
/// residual) rejected.
fn update_report() -> CoreToHost {
    let mut residuals = Vec::new();
    let _ = residuals.push(0.5);
    let _ = residuals.push(3.25);
    let _ = residuals.push(120.0);
    CoreToHost::UpdateReport(UpdateReport {
        frame_id: 42,
        part: 0,
        outcome: UpdateOutcome::Applied,
        accepted: 2,
        rejected: 1,
        residuals,
        prediction_error: 0.004,
    })
}

/// A sampling report of a gap: four samples lost to a FIFO overflow.
fn sampling_gap() -> CoreToHost {
    CoreToHost::Sampling(SamplingReport {
        t_us: 2_000_000,
        event: SamplingEvent::Gap(SampleGap {
            from_us: 1_950_000,
            to_us: 2_000_000,
            lost: 4,
            cause: GapCause::FifoOverflow,
        }),
        samples: 200,
        lost: 4,
        part_resets: 0,
        late_reads: 1,
        drift_ppm: 120.0,
    })
}
