//! Size bounds: the worst-case instance of every message kind (longest varints, fullest lists,
//! largest variants) fits the exported limits; prints the table quoted in PROTOCOL.md
//! (`cargo test -p protocol --test sizes -- --nocapture`).

use protocol::*;

fn worst_correspondence() -> Correspondence {
    Correspondence {
        m_n: [f32::MAX; 2],
        cov_n: [f32::MAX; 3],
        m_w: [f32::MAX; 3],
        cov_w: [f32::MAX; 6],
    }
}

fn worst_contour() -> ContourPoint {
    ContourPoint {
        m_w: [f32::MAX; 3],
        cov_w: [f32::MAX; 6],
        n: [f32::MAX; 2],
        d: f32::MAX,
        var_d: f32::MAX,
    }
}

fn worst_host() -> Vec<(&'static str, HostToCore)> {
    let v = Version {
        major: u16::MAX,
        minor: u16::MAX,
    };
    let mut cfg = samples::config();
    cfg.still_samples = u16::MAX;
    cfg.state_every = u16::MAX;
    cfg.session = u32::MAX;
    vec![
        ("Hello", HostToCore::Hello(Hello { version: v })),
        ("Configure", HostToCore::Configure(cfg)),
        (
            "Init",
            HostToCore::Init(Init {
                position: [1.0; 3],
                attitude: InitAttitude::Full([1.0; 4]),
            }),
        ),
        (
            "Imu",
            HostToCore::Imu(ImuSample {
                t_us: u64::MAX,
                gyro: [1.0; 3],
                accel: [1.0; 3],
                trigger: true,
            }),
        ),
        (
            "Correspondences",
            HostToCore::Correspondences(Correspondences {
                frame_id: u32::MAX,
                trigger_us: u64::MAX,
                part: u8::MAX,
                parts: u8::MAX,
                items: [worst_correspondence(); MAX_CORRESPONDENCES_PER_MESSAGE]
                    .into_iter()
                    .collect(),
            }),
        ),
        ("Reset", HostToCore::Reset),
        ("Query", HostToCore::Query),
        (
            "Resume",
            HostToCore::Resume(Resume {
                t_us: u64::MAX,
                s_w: [1.0; 3],
                q_sw: [1.0; 4],
                v_w: [1.0; 3],
                a_w: [1.0; 3],
                omega_s: [1.0; 3],
                gyro_bias: [1.0; 3],
                accel_bias: [1.0; 3],
            }),
        ),
        (
            "Sampling",
            HostToCore::Sampling(Sampling {
                source: SampleSource::Core {
                    trigger_every: u16::MAX,
                },
                raw_imu: true,
            }),
        ),
        (
            "Contours",
            HostToCore::Contours(Contours {
                frame_id: u32::MAX,
                trigger_us: u64::MAX,
                part: u8::MAX,
                parts: u8::MAX,
                items: [worst_contour(); MAX_CORRESPONDENCES_PER_MESSAGE]
                    .into_iter()
                    .collect(),
            }),
        ),
    ]
}

fn worst_core() -> Vec<(&'static str, CoreToHost)> {
    let v = Version {
        major: u16::MAX,
        minor: u16::MAX,
    };
    vec![
        ("HelloAck", worst_hello_ack(v)),
        ("Error", worst_error(v)),
        (
            "PosePrediction",
            CoreToHost::PosePrediction(PosePrediction {
                frame_id: u32::MAX,
                t_us: u64::MAX,
                c_w: [1.0; 3],
                q_cw: [1.0; 4],
                cov: [1.0; 21],
            }),
        ),
        ("State", worst_state()),
        (
            "UpdateReport",
            CoreToHost::UpdateReport(UpdateReport {
                frame_id: u32::MAX,
                part: u8::MAX,
                outcome: UpdateOutcome::NotRunning,
                accepted: u16::MAX,
                rejected: u16::MAX,
                residuals: [1.0; MAX_CORRESPONDENCES_PER_MESSAGE].into_iter().collect(),
                prediction_error: 1.0,
            }),
        ),
        (
            "Status",
            CoreToHost::Status(Status {
                t_us: u64::MAX,
                mode: Mode::Reinitialising,
                reason: StatusReason::NonFiniteState,
            }),
        ),
        (
            "Trigger",
            CoreToHost::Trigger(Trigger {
                frame_id: u32::MAX,
                t_us: u64::MAX,
            }),
        ),
        (
            "RawImu",
            CoreToHost::RawImu(ImuSample {
                t_us: u64::MAX,
                gyro: [1.0; 3],
                accel: [1.0; 3],
                trigger: true,
            }),
        ),
        ("Sampling", worst_sampling()),
    ]
}

/// `HelloAck` with version `v` and every capacity at its type's maximum.
fn worst_hello_ack(v: Version) -> CoreToHost {
    CoreToHost::HelloAck(HelloAck {
        version: v,
        model: Some(ModelKind::Acc),
        capacities: Capacities {
            max_frame_len: u16::MAX,
            max_correspondences_per_message: u16::MAX,
            max_correspondences_per_frame: u16::MAX,
            delay_buffer_samples: u16::MAX,
            max_pending_frames: u16::MAX,
            scalar_bits: u8::MAX,
        },
        session: u32::MAX,
    })
}

/// The longest `Error`: whichever of the codes with the largest payloads encodes longest.
fn worst_error(v: Version) -> CoreToHost {
    let errors = [
        ErrorCode::VersionMismatch { core: v, host: v },
        ErrorCode::TimestampNotIncreasing {
            last_us: u64::MAX,
            got_us: u64::MAX,
        },
        ErrorCode::TimestampGap {
            last_us: u64::MAX,
            got_us: u64::MAX,
        },
        ErrorCode::TooManyCorrespondences { frame_id: u32::MAX },
        ErrorCode::Invalid(InvalidField::CorrespondenceCovariance { index: u8::MAX }),
    ];
    errors
        .into_iter()
        .map(CoreToHost::error)
        .max_by_key(|m| body_len(m).unwrap())
        .unwrap()
}

/// `State` with the longest time stamp (floats encode at a fixed size).
fn worst_state() -> CoreToHost {
    CoreToHost::State(StateReport {
        t_us: u64::MAX,
        s_w: [1.0; 3],
        q_sw: [1.0; 4],
        v_w: [1.0; 3],
        a_w: [1.0; 3],
        omega_s: [1.0; 3],
        gyro_bias: [1.0; 3],
        accel_bias: [1.0; 3],
        health: Health {
            mode: Mode::Reinitialising,
            covariance_frobenius: 1.0,
            residual_lowpass: 1.0,
            quaternion_norm_error: 1.0,
        },
        cov: [1.0; 21],
    })
}

/// A `Sampling` report of a gap (the only event with a payload), every counter at its maximum.
fn worst_sampling() -> CoreToHost {
    CoreToHost::Sampling(SamplingReport {
        t_us: u64::MAX,
        event: SamplingEvent::Gap(SampleGap {
            from_us: u64::MAX,
            to_us: u64::MAX,
            lost: u32::MAX,
            cause: GapCause::Unexplained,
        }),
        samples: u32::MAX,
        lost: u32::MAX,
        part_resets: u32::MAX,
        late_reads: u32::MAX,
        drift_ppm: 1.0,
    })
}

fn frame_len<T: serde::Serialize>(m: &T) -> usize {
    let mut buf = [0u8; MAX_FRAME_LEN];
    encode_frame(m, &mut buf).unwrap().len()
}

#[test]
fn worst_case_messages_fit_the_exported_bounds() {
    println!("{:<18} {:>10} {:>10}", "message", "max body", "max frame");
    let mut largest = 0;
    let rows: Vec<(String, usize, usize)> = worst_host()
        .iter()
        .map(|(n, m)| (format!("→ {n}"), body_len(m).unwrap(), frame_len(m)))
        .chain(
            worst_core()
                .iter()
                .map(|(n, m)| (format!("← {n}"), body_len(m).unwrap(), frame_len(m))),
        )
        .collect();
    for (name, body, frame) in &rows {
        println!("{name:<18} {body:>10} {frame:>10}");
        assert!(
            *body <= MAX_PAYLOAD_LEN,
            "{name}: {body} > {MAX_PAYLOAD_LEN}"
        );
        assert!(*frame <= MAX_FRAME_LEN, "{name}: {frame} > {MAX_FRAME_LEN}");
        largest = largest.max(*frame);
    }
    println!("largest frame {largest} of at most {MAX_FRAME_LEN}");
    // The bound is not wildly loose either: the largest message uses most of it.
    assert!(
        largest * 10 >= MAX_FRAME_LEN * 8,
        "{largest} vs {MAX_FRAME_LEN}"
    );
}

#[test]
fn every_message_kind_has_a_worst_case() {
    // Adding a message kind without a worst case here would leave its size unchecked.
    let host: Vec<&str> = worst_host().iter().map(|(_, m)| m.kind()).collect();
    assert_eq!(
        host,
        [
            "Hello",
            "Configure",
            "Init",
            "Imu",
            "Correspondences",
            "Reset",
            "Query",
            "Resume",
            "Sampling",
            "Contours"
        ]
    );
    let core: Vec<&str> = worst_core().iter().map(|(_, m)| m.kind()).collect();
    assert_eq!(
        core,
        [
            "HelloAck",
            "Error",
            "PosePrediction",
            "State",
            "UpdateReport",
            "Status",
            "Trigger",
            "RawImu",
            "Sampling"
        ]
    );
}
