//! Property tests of the framing and the messages: round trips, corruption, resynchronisation,
//! chunking, and a million random buffers through the decoder.

use proptest::collection::vec;
use proptest::prelude::*;
use protocol::*;

// ----------------------------------------------------------------------------------------------
// Strategies
// ----------------------------------------------------------------------------------------------

/// Any f32 bit pattern, NaNs and infinities included: the wire carries them and the round trip
/// must keep every bit (validation, not framing, rejects them).
fn f() -> impl Strategy<Value = f32> {
    any::<u32>().prop_map(f32::from_bits)
}

fn a<const N: usize>() -> impl Strategy<Value = [f32; N]> {
    vec(f(), N).prop_map(|v| v.try_into().unwrap())
}

fn version() -> impl Strategy<Value = Version> {
    (any::<u16>(), any::<u16>()).prop_map(|(major, minor)| Version { major, minor })
}

fn model() -> impl Strategy<Value = ModelKind> {
    prop_oneof![
        Just(ModelKind::Gyro),
        Just(ModelKind::Gravity),
        Just(ModelKind::Acc),
        Just(ModelKind::Vision)
    ]
}

fn config() -> impl Strategy<Value = Config> {
    (
        model(),
        a::<6>(),
        a::<8>(),
        a::<4>(),
        a::<3>(),
        a::<5>(),
        a::<2>(),
        any::<[u16; 2]>(),
        any::<u32>(),
    )
        .prop_map(
            |(model, n, s, q_cs, c_s, d, r, [still_samples, state_every], session)| Config {
                model,
                noise: NoiseParams {
                    motion: n[0],
                    angular: n[1],
                    gyro_bias_walk: n[2],
                    accel_bias_walk: n[3],
                    gyro_meas: n[4],
                    accel_meas: n[5],
                },
                init_sigma: InitSigma {
                    position: s[0],
                    velocity: s[1],
                    acceleration: s[2],
                    tilt: s[3],
                    yaw: s[4],
                    angular_velocity: s[5],
                    gyro_bias: s[6],
                    accel_bias: s[7],
                },
                hand_eye: HandEye { q_cs, c_s },
                gate: d[0],
                divergence: DivergenceParams {
                    residual_lowpass: d[1],
                    residual_threshold: d[2],
                    covariance_frobenius: d[3],
                    quaternion_norm: d[4],
                },
                imu_rate_hz: r[0],
                camera_rate_hz: r[1],
                still_samples,
                state_every,
                session,
            },
        )
}

fn correspondence() -> impl Strategy<Value = Correspondence> {
    (a::<2>(), a::<3>(), a::<3>(), a::<6>()).prop_map(|(m_n, cov_n, m_w, cov_w)| Correspondence {
        m_n,
        cov_n,
        m_w,
        cov_w,
    })
}

fn contour() -> impl Strategy<Value = ContourPoint> {
    (a::<3>(), a::<6>(), a::<2>(), f(), f()).prop_map(|(m_w, cov_w, n, d, var_d)| ContourPoint {
        m_w,
        cov_w,
        n,
        d,
        var_d,
    })
}

fn host_message() -> impl Strategy<Value = HostToCore> {
    prop_oneof![
        version().prop_map(|version| HostToCore::Hello(Hello { version })),
        config().prop_map(HostToCore::Configure),
        (
            a::<3>(),
            prop_oneof![
                Just(InitAttitude::Gravity),
                f().prop_map(InitAttitude::GravityAndYaw),
                a::<4>().prop_map(InitAttitude::Full),
            ]
        )
            .prop_map(|(position, attitude)| HostToCore::Init(Init { position, attitude })),
        (any::<u64>(), a::<3>(), a::<3>(), any::<bool>()).prop_map(
            |(t_us, gyro, accel, trigger)| {
                HostToCore::Imu(ImuSample {
                    t_us,
                    gyro,
                    accel,
                    trigger,
                })
            }
        ),
        (
            any::<u32>(),
            any::<u64>(),
            any::<u8>(),
            any::<u8>(),
            vec(correspondence(), 0..=MAX_CORRESPONDENCES_PER_MESSAGE)
        )
            .prop_map(|(frame_id, trigger_us, part, parts, items)| {
                HostToCore::Correspondences(Correspondences {
                    frame_id,
                    trigger_us,
                    part,
                    parts,
                    items: items.into_iter().collect(),
                })
            }),
        Just(HostToCore::Reset),
        Just(HostToCore::Query),
        (
            any::<u64>(),
            a::<3>(),
            a::<4>(),
            a::<3>(),
            a::<3>(),
            a::<3>(),
            a::<3>(),
            a::<3>()
        )
            .prop_map(
                |(t_us, s_w, q_sw, v_w, a_w, omega_s, gyro_bias, accel_bias)| {
                    HostToCore::Resume(Resume {
                        t_us,
                        s_w,
                        q_sw,
                        v_w,
                        a_w,
                        omega_s,
                        gyro_bias,
                        accel_bias,
                    })
                }
            ),
        (any::<u64>(), any::<bool>())
            .prop_map(|(t_us, trigger)| HostToCore::Tick(Tick { t_us, trigger })),
        (
            any::<u32>(),
            any::<u64>(),
            any::<u8>(),
            any::<u8>(),
            vec(contour(), 0..=MAX_CORRESPONDENCES_PER_MESSAGE)
        )
            .prop_map(|(frame_id, trigger_us, part, parts, items)| {
                HostToCore::Contours(Contours {
                    frame_id,
                    trigger_us,
                    part,
                    parts,
                    items: items.into_iter().collect(),
                })
            }),
    ]
}

fn mode() -> impl Strategy<Value = Mode> {
    prop_oneof![
        Just(Mode::Unconfigured),
        Just(Mode::AwaitingInit),
        Just(Mode::Initialising),
        Just(Mode::Tracking),
        Just(Mode::DeadReckoning),
        Just(Mode::Diverged),
        Just(Mode::Reinitialising),
    ]
}

fn reason() -> impl Strategy<Value = StatusReason> {
    prop_oneof![
        Just(StatusReason::Configured),
        Just(StatusReason::HostRequest),
        Just(StatusReason::InitComplete),
        Just(StatusReason::VisionAccepted),
        Just(StatusReason::NoVision),
        Just(StatusReason::ResidualLowpass),
        Just(StatusReason::CovarianceNorm),
        Just(StatusReason::QuaternionNorm),
        Just(StatusReason::NonFiniteState),
        Just(StatusReason::TimeJump),
    ]
}

fn decode_error() -> impl Strategy<Value = DecodeError> {
    prop_oneof![
        Just(DecodeError::Oversized),
        Just(DecodeError::Cobs),
        Just(DecodeError::Truncated),
        Just(DecodeError::Crc),
        Just(DecodeError::Malformed),
        Just(DecodeError::TrailingBytes),
    ]
}

fn invalid_field() -> impl Strategy<Value = InvalidField> {
    prop_oneof![
        Just(InvalidField::NoiseParams),
        Just(InvalidField::InitSigma),
        Just(InvalidField::HandEye),
        Just(InvalidField::Gate),
        Just(InvalidField::Divergence),
        Just(InvalidField::Rate),
        Just(InvalidField::StillSamples),
        Just(InvalidField::InitPosition),
        Just(InvalidField::InitAttitude),
        Just(InvalidField::ImuNotFinite),
        Just(InvalidField::ImuOutOfRange),
        Just(InvalidField::CorrespondencePart),
        any::<u8>().prop_map(|index| InvalidField::CorrespondenceNotFinite { index }),
        any::<u8>().prop_map(|index| InvalidField::CorrespondenceCovariance { index }),
        Just(InvalidField::CovarianceThreshold),
        Just(InvalidField::Session),
        Just(InvalidField::Resume),
        Just(InvalidField::Sampling),
        any::<u8>().prop_map(|index| InvalidField::ContourNormal { index }),
    ]
}

fn error_code() -> impl Strategy<Value = ErrorCode> {
    prop_oneof![
        (version(), version()).prop_map(|(core, host)| ErrorCode::VersionMismatch { core, host }),
        decode_error().prop_map(ErrorCode::Decode),
        invalid_field().prop_map(ErrorCode::Invalid),
        Just(ErrorCode::NoHandshake),
        Just(ErrorCode::NotConfigured),
        (any::<u64>(), any::<u64>())
            .prop_map(|(last_us, got_us)| ErrorCode::TimestampNotIncreasing { last_us, got_us }),
        (any::<u64>(), any::<u64>())
            .prop_map(|(last_us, got_us)| ErrorCode::TimestampGap { last_us, got_us }),
        any::<u32>().prop_map(|frame_id| ErrorCode::TooManyCorrespondences { frame_id }),
    ]
}

fn outcome() -> impl Strategy<Value = UpdateOutcome> {
    prop_oneof![
        Just(UpdateOutcome::Applied),
        Just(UpdateOutcome::TooOld),
        Just(UpdateOutcome::Duplicate),
        Just(UpdateOutcome::UnknownFrame),
        Just(UpdateOutcome::NotRunning),
    ]
}

fn core_message() -> impl Strategy<Value = CoreToHost> {
    prop_oneof![
        (
            version(),
            proptest::option::of(model()),
            any::<[u16; 5]>(),
            any::<u8>(),
            any::<u32>()
        )
            .prop_map(|(version, model, c, scalar_bits, session)| {
                CoreToHost::HelloAck(HelloAck {
                    version,
                    model,
                    capacities: Capacities {
                        max_frame_len: c[0],
                        max_correspondences_per_message: c[1],
                        max_correspondences_per_frame: c[2],
                        delay_buffer_samples: c[3],
                        max_pending_frames: c[4],
                        scalar_bits,
                    },
                    session,
                })
            }),
        error_code().prop_map(CoreToHost::error),
        (any::<u32>(), any::<u64>(), a::<3>(), a::<4>(), a::<21>()).prop_map(
            |(frame_id, t_us, c_w, q_cw, cov)| {
                CoreToHost::PosePrediction(PosePrediction {
                    frame_id,
                    t_us,
                    c_w,
                    q_cw,
                    cov,
                })
            }
        ),
        (
            any::<u64>(),
            a::<19>(),
            a::<6>(),
            a::<3>(),
            mode(),
            a::<21>()
        )
            .prop_map(|(t_us, x, y, h, mode, cov)| {
                let v3 = |i: usize| [x[i], x[i + 1], x[i + 2]];
                CoreToHost::State(StateReport {
                    t_us,
                    s_w: v3(0),
                    q_sw: [x[3], x[4], x[5], x[6]],
                    v_w: v3(7),
                    a_w: v3(10),
                    omega_s: v3(13),
                    gyro_bias: v3(16),
                    accel_bias: [y[0], y[1], y[2]],
                    health: Health {
                        mode,
                        covariance_frobenius: h[0],
                        residual_lowpass: h[1],
                        quaternion_norm_error: h[2],
                    },
                    cov,
                })
            }),
        (
            any::<u32>(),
            any::<u8>(),
            outcome(),
            any::<u16>(),
            any::<u16>(),
            vec(f(), 0..=MAX_CORRESPONDENCES_PER_MESSAGE),
            f()
        )
            .prop_map(
                |(frame_id, part, outcome, accepted, rejected, r, prediction_error)| {
                    CoreToHost::UpdateReport(UpdateReport {
                        frame_id,
                        part,
                        outcome,
                        accepted,
                        rejected,
                        residuals: r.into_iter().collect(),
                        prediction_error,
                    })
                }
            ),
        (any::<u64>(), mode(), reason())
            .prop_map(|(t_us, mode, reason)| CoreToHost::Status(Status { t_us, mode, reason })),
    ]
}

// ----------------------------------------------------------------------------------------------
// Helpers
// ----------------------------------------------------------------------------------------------

fn frame<T: serde::Serialize>(msg: &T) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME_LEN];
    encode_frame(msg, &mut out)
        .expect("every message fits a frame")
        .to_vec()
}

/// Bit-exact equality through the encoding (NaN payloads included): postcard's encoding of
/// these types is canonical, so equal bytes mean equal values.
fn same<T: serde::Serialize>(a: &T, b: &T) -> bool {
    frame(a) == frame(b)
}

fn decode_all<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Vec<Result<T, DecodeError>> {
    let mut dec = Decoder::new();
    dec.feed::<T>(bytes).collect()
}

// ----------------------------------------------------------------------------------------------
// Properties
// ----------------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn every_host_message_round_trips(msg in host_message()) {
        let bytes = frame(&msg);
        prop_assert!(bytes.len() <= MAX_FRAME_LEN);
        let got = decode_all::<HostToCore>(&bytes);
        prop_assert_eq!(got.len(), 1);
        let back = got[0].clone().unwrap();
        prop_assert!(same(&back, &msg), "{:?} != {:?}", back, msg);
    }

    #[test]
    fn every_core_message_round_trips(msg in core_message()) {
        let bytes = frame(&msg);
        prop_assert!(bytes.len() <= MAX_FRAME_LEN);
        let got = decode_all::<CoreToHost>(&bytes);
        prop_assert_eq!(got.len(), 1);
        let back = got[0].clone().unwrap();
        prop_assert!(same(&back, &msg), "{:?} != {:?}", back, msg);
    }

    #[test]
    fn any_single_bit_flip_is_rejected_and_the_next_frame_decodes(
        msg in host_message(),
        next in host_message(),
        bit in any::<prop::sample::Index>(),
    ) {
        let mut bytes = frame(&msg);
        let bit = bit.index(bytes.len() * 8);
        bytes[bit / 8] ^= 1 << (bit % 8);
        bytes.extend(frame(&next));
        let got = decode_all::<HostToCore>(&bytes);
        let (last, before) = got.split_last().unwrap();
        prop_assert!(before.iter().all(|r| r.is_err()), "corrupted frame accepted: {:?}", before);
        prop_assert!(same(last.as_ref().unwrap(), &next));
    }

    #[test]
    fn a_truncated_frame_is_rejected_and_the_next_frame_decodes(
        msg in host_message(),
        next in host_message(),
        cut in any::<prop::sample::Index>(),
    ) {
        let mut bytes = frame(&msg);
        // Keep the opening delimiter and at least one byte; drop the closing delimiter and at
        // least one encoded byte (without the latter the next frame's opening delimiter would
        // close this one, complete).
        let keep = 2 + cut.index(bytes.len() - 3);
        bytes.truncate(keep);
        bytes.extend(frame(&next));
        let got = decode_all::<HostToCore>(&bytes);
        let (last, before) = got.split_last().unwrap();
        prop_assert!(before.iter().all(|r| r.is_err()), "truncated frame accepted: {:?}", before);
        prop_assert!(same(last.as_ref().unwrap(), &next));
    }

    #[test]
    fn garbage_between_frames_is_rejected_and_every_frame_decodes(
        msgs in vec(host_message(), 1..6),
        garbage in vec(vec(any::<u8>(), 0..300), 6),
    ) {
        let mut bytes = Vec::new();
        for (m, g) in msgs.iter().zip(&garbage) {
            bytes.extend(g);
            bytes.extend(frame(m));
        }
        let good: Vec<HostToCore> =
            decode_all::<HostToCore>(&bytes).into_iter().filter_map(Result::ok).collect();
        prop_assert_eq!(good.len(), msgs.len());
        for (g, m) in good.iter().zip(&msgs) {
            prop_assert!(same(g, m));
        }
    }

    #[test]
    fn decoding_does_not_depend_on_chunking(
        msgs in vec(core_message(), 1..5),
        cuts in vec(any::<prop::sample::Index>(), 0..20),
    ) {
        let bytes: Vec<u8> = msgs.iter().flat_map(frame).collect();
        let whole = decode_all::<CoreToHost>(&bytes);
        let mut cuts: Vec<usize> = cuts.iter().map(|c| c.index(bytes.len() + 1)).collect();
        cuts.sort_unstable();
        let mut dec = Decoder::new();
        let mut chunked = Vec::new();
        let mut start = 0;
        for cut in cuts.into_iter().chain([bytes.len()]) {
            chunked.extend(dec.feed::<CoreToHost>(&bytes[start..cut]));
            start = cut;
        }
        prop_assert_eq!(whole.len(), chunked.len());
        for (w, c) in whole.iter().zip(&chunked) {
            prop_assert!(same(w.as_ref().unwrap(), c.as_ref().unwrap()));
        }
    }
}

/// Every split of a fixed stream into two chunks, at every byte boundary, decodes identically;
/// so does feeding it one byte at a time.
#[test]
fn every_two_chunk_split_decodes_identically() {
    let mut bytes = Vec::new();
    for (_, m) in samples::core_messages() {
        bytes.extend(frame(&m));
    }
    let whole = decode_all::<CoreToHost>(&bytes);
    assert_eq!(whole.len(), samples::core_messages().len());
    for cut in 0..=bytes.len() {
        let mut dec = Decoder::new();
        let mut got: Vec<_> = dec.feed::<CoreToHost>(&bytes[..cut]).collect();
        got.extend(dec.feed::<CoreToHost>(&bytes[cut..]));
        assert_eq!(got, whole, "split at {cut}");
    }
    let mut dec = Decoder::new();
    let by_byte: Vec<_> = bytes
        .iter()
        .filter_map(|&b| dec.push::<CoreToHost>(b))
        .collect();
    assert_eq!(by_byte, whole);
}

/// Every bit of every sample frame flipped in turn: rejected, and the next frame decodes.
#[test]
fn every_single_bit_flip_of_every_sample_frame_is_caught() {
    let next = frame(&HostToCore::Reset);
    let mut flips = 0;
    for (name, msg) in samples::host_messages() {
        let good = frame(&msg);
        for bit in 0..good.len() * 8 {
            let mut bytes = good.clone();
            bytes[bit / 8] ^= 1 << (bit % 8);
            bytes.extend(&next);
            let got = decode_all::<HostToCore>(&bytes);
            let (last, before) = got.split_last().unwrap();
            assert!(
                before.iter().all(|r| r.is_err()),
                "{name} bit {bit}: {before:?}"
            );
            assert_eq!(last, &Ok(HostToCore::Reset), "{name} bit {bit}");
            flips += 1;
        }
    }
    assert!(flips > 2000);
}

/// A small, fast, deterministic generator, so that a million buffers cost little.
struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

/// 10^6 random buffers (pure noise, noise with many zeros, and mutated valid frames) through
/// both decoders: no panic, nothing but an intact original is ever accepted, and the decoder is
/// still in sync afterwards.
#[test]
fn a_million_random_buffers_do_not_panic_the_decoder() {
    let mut rng = XorShift(0x9E37_79B9_7F4A_7C15);
    let valid: Vec<Vec<u8>> = samples::host_messages()
        .iter()
        .map(|(_, m)| frame(m))
        .collect();
    let mut host = Decoder::new();
    let mut core = Decoder::new();
    let mut buf = Vec::with_capacity(2048);
    let mut accepted = 0usize;
    for i in 0..1_000_000u32 {
        buf.clear();
        match i % 3 {
            0 => {
                let len = (rng.next() % 64) as usize;
                buf.extend((0..len).map(|_| rng.next() as u8));
            }
            1 => {
                let len = (rng.next() % 64) as usize;
                buf.extend((0..len).map(|_| {
                    let r = rng.next();
                    if r.is_multiple_of(5) {
                        0
                    } else {
                        (r >> 8) as u8
                    }
                }));
            }
            _ => {
                let base = &valid[(rng.next() % valid.len() as u64) as usize];
                buf.extend(base);
                for _ in 0..1 + rng.next() % 4 {
                    let at = (rng.next() % buf.len() as u64) as usize;
                    buf[at] = rng.next() as u8;
                }
            }
        }
        for msg in host.feed::<HostToCore>(&buf).filter_map(Result::ok) {
            // A mutation that rewrote a byte with its own value leaves a frame intact.
            assert!(
                valid.contains(&frame(&msg)),
                "corrupted frame accepted: {msg:?}"
            );
            accepted += 1;
        }
        // The other direction's decoder sees foreign frames too: it must simply not panic.
        core.feed::<CoreToHost>(&buf).for_each(drop);
    }
    assert!(
        accepted > 0,
        "no intact frame in a million buffers: generator broken"
    );
    // Still in sync: a clean frame after all that noise decodes.
    let after = frame(&HostToCore::Reset);
    let got: Vec<_> = host.feed::<HostToCore>(&after).collect();
    assert_eq!(got.last(), Some(&Ok(HostToCore::Reset)));
}
