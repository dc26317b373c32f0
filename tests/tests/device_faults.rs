//! Bad input to the fusion core's device loop: every kind is refused with a typed reason,
//! counted, and leaves the filter untouched; faults of the paper's system (no model in view,
//! outliers, divergence, lost frames) are handled as it does.

use firmware_sim::sim::trajectory::Kinematics;
use fusion_core::{Device, DeviceIo};
use nalgebra::Vector3;
use protocol::{
    CoreToHost, Correspondences, DecodeError, ErrorCode, Hello, HostToCore, ImuSample,
    InvalidField, MAX_FRAME_LEN, Mode, ModelKind, PROTOCOL_VERSION, StatusReason, UpdateOutcome,
    encode_frame, samples,
};
use tests::harness::{Driver, Scenario, errors, scenes};

fn scenario(model: ModelKind) -> Scenario {
    scenes::standard(model, 30.0, 2.0, 11)
}

/// A driver that has tracked for `seconds`.
fn tracking<'s>(sc: &'s Scenario, seconds: f64) -> Driver<'s, f64> {
    let mut d = Driver::<f64>::new(sc);
    while (d.k as f64) < seconds * sc.imu_rate_hz {
        d.step();
    }
    assert_eq!(d.device.mode(), Mode::Tracking);
    d
}

/// The acc scenario with a lower residual threshold, and the same with the model moved by 30 cm
/// (say, the target was moved): every correspondence of the second disagrees with the first.
fn with_model_moved() -> (Scenario, Scenario) {
    let mut sc = scenario(ModelKind::Acc);
    sc.config.divergence.residual_threshold = 20.0;
    let mut shifted = scenario(ModelKind::Acc);
    shifted.config = sc.config;
    shifted.model_offset = Vector3::new(0.0, 0.3, 0.0);
    (sc, shifted)
}

/// Steps `d` (not answering frames) to its next pose prediction: the prediction and the truth
/// at its trigger.
fn next_prediction(d: &mut Driver<'_, f64>) -> (protocol::PosePrediction, Kinematics) {
    loop {
        let msg = d.next_imu();
        if let Some(p) = d.send(&msg).into_iter().find_map(|a| match a {
            CoreToHost::PosePrediction(p) => Some(p),
            _ => None,
        }) {
            break (p, d.last.unwrap().0);
        }
    }
}

/// The update report among `answers`.
fn report_in(answers: Vec<CoreToHost>) -> protocol::UpdateReport {
    answers
        .into_iter()
        .find_map(|a| match a {
            CoreToHost::UpdateReport(r) => Some(r),
            _ => None,
        })
        .expect("an update report")
}

fn errors_in(answers: &[CoreToHost]) -> Vec<ErrorCode> {
    answers
        .iter()
        .filter_map(|a| match a {
            CoreToHost::Error(e) => Some(e.code),
            _ => None,
        })
        .collect()
}

fn imu(t_us: u64, gyro: [f32; 3], accel: [f32; 3]) -> HostToCore {
    HostToCore::Imu(ImuSample {
        t_us,
        gyro,
        accel,
        trigger: false,
    })
}

#[test]
fn messages_out_of_order_are_refused_with_a_reason() {
    let mut dev = Device::<f32>::new();
    let mut answers = Vec::new();
    dev.handle(&HostToCore::Reset, &mut |m| answers.push(m));
    dev.handle(&HostToCore::Configure(samples::config()), &mut |m| {
        answers.push(m)
    });
    assert_eq!(
        errors_in(&answers),
        [ErrorCode::NoHandshake, ErrorCode::NoHandshake]
    );
    answers.clear();
    dev.handle(
        &HostToCore::Hello(Hello {
            version: PROTOCOL_VERSION,
        }),
        &mut |m| answers.push(m),
    );
    assert!(matches!(answers[0], CoreToHost::HelloAck(_)));
    answers.clear();
    let init = samples::host_messages()[2].1.clone();
    dev.handle(&init, &mut |m| answers.push(m));
    dev.handle(&imu(1, [0.0; 3], [0.0, 0.0, 9.81]), &mut |m| {
        answers.push(m)
    });
    assert_eq!(
        errors_in(&answers),
        [ErrorCode::NotConfigured, ErrorCode::NotConfigured]
    );
    assert_eq!(dev.counters().out_of_order, 4);
    // Correspondences before the filter runs: refused as not running.
    answers.clear();
    dev.handle(&HostToCore::Configure(samples::config()), &mut |m| {
        answers.push(m)
    });
    let corr = samples::host_messages()[5].1.clone();
    dev.handle(&corr, &mut |m| answers.push(m));
    assert!(answers.iter().any(|a| matches!(a,
        CoreToHost::UpdateReport(r) if r.outcome == UpdateOutcome::NotRunning)));
}

#[test]
fn bad_imu_samples_are_refused_and_leave_the_state_untouched() {
    let sc = scenario(ModelKind::Acc);
    let mut d = tracking(&sc, 5.0);
    let before = d.device.filter().clone();
    let last_t = before.t_us;
    let nan = f32::NAN;
    let cases = [
        (
            imu(last_t + 5000, [nan, 0.0, 0.0], [0.0, 0.0, 9.81]),
            ErrorCode::Invalid(InvalidField::ImuNotFinite),
        ),
        (
            imu(last_t + 5000, [0.0; 3], [0.0, f32::INFINITY, 9.81]),
            ErrorCode::Invalid(InvalidField::ImuNotFinite),
        ),
        (
            imu(last_t + 5000, [500.0, 0.0, 0.0], [0.0, 0.0, 9.81]),
            ErrorCode::Invalid(InvalidField::ImuOutOfRange),
        ),
        (
            imu(last_t + 5000, [0.0; 3], [0.0, 0.0, 1e5]),
            ErrorCode::Invalid(InvalidField::ImuOutOfRange),
        ),
        (
            imu(last_t, [0.0; 3], [0.0, 0.0, 9.81]),
            ErrorCode::TimestampNotIncreasing {
                last_us: last_t,
                got_us: last_t,
            },
        ),
        (
            imu(last_t - 100_000, [0.0; 3], [0.0, 0.0, 9.81]),
            ErrorCode::TimestampNotIncreasing {
                last_us: last_t,
                got_us: last_t - 100_000,
            },
        ),
        (
            imu(last_t + 5_000_000, [0.0; 3], [0.0, 0.0, 9.81]),
            ErrorCode::TimestampGap {
                last_us: last_t,
                got_us: last_t + 5_000_000,
            },
        ),
    ];
    for (msg, expected) in &cases {
        let answers = d.send(msg);
        assert_eq!(errors_in(&answers), [*expected], "{msg:?}");
        assert_eq!(d.device.filter(), &before, "state changed by {msg:?}");
    }
    let c = d.device.counters();
    assert_eq!((c.invalid_messages, c.imu_time_rejected), (4, 3));
    // The stream goes on normally afterwards.
    for _ in 0..400 {
        d.step();
    }
    let (truth, _) = d.last.unwrap();
    assert_eq!(d.device.mode(), Mode::Tracking);
    assert!(errors::position(&d.device, &truth) < 0.02);
}

#[test]
fn a_confirmed_clock_jump_reinitialises_from_the_last_good_position() {
    let sc = scenario(ModelKind::Gravity);
    let mut d = tracking(&sc, 5.0);
    let t = d.device.filter().t_us;
    let still = |t_us| imu(t_us, [0.0; 3], [0.0, 0.0, 9.81]);
    let mut reasons = Vec::new();
    for i in 0..3u64 {
        let answers = d.send(&still(t + 10_000_000 + i * 5000));
        reasons.extend(answers.iter().filter_map(|a| match a {
            CoreToHost::Status(s) => Some((s.mode, s.reason)),
            _ => None,
        }));
    }
    assert_eq!(reasons, [(Mode::Reinitialising, StatusReason::TimeJump)]);
    assert_eq!(d.device.counters().clock_jumps, 1);
    assert_eq!(d.device.counters().imu_time_rejected, 2);
}

#[test]
fn correspondences_too_old_duplicated_or_unknown_are_refused() {
    let sc = scenario(ModelKind::Acc);
    let mut d = tracking(&sc, 3.0);
    d.answer_frames = false;
    // Collect predictions by hand from here on.
    let mut preds = Vec::new();
    for _ in 0..200 {
        let msg = d.next_imu();
        for a in d.send(&msg) {
            if let CoreToHost::PosePrediction(p) = a {
                preds.push((p, d.last.unwrap().0));
            }
        }
    }
    let outcome = |d: &mut Driver<f64>, msg: &HostToCore| -> UpdateOutcome {
        d.send(msg)
            .into_iter()
            .find_map(|a| match a {
                CoreToHost::UpdateReport(r) => Some(r.outcome),
                _ => None,
            })
            .expect("an update report")
    };
    let part = |d: &mut Driver<f64>, i: usize| {
        let (p, truth) = &preds[i];
        let corrs = d.observe(truth);
        HostToCore::Correspondences(
            Correspondences::split(p.frame_id, p.t_us, &corrs)
                .unwrap()
                .next()
                .unwrap(),
        )
    };
    // The newest frame applies once; its duplicate is refused.
    let last = preds.len() - 1;
    let newest = part(&mut d, last);
    assert_eq!(outcome(&mut d, &newest), UpdateOutcome::Applied);
    assert_eq!(outcome(&mut d, &newest), UpdateOutcome::Duplicate);
    // An older frame after a newer one was applied would be overwritten: refused as too old.
    let older = part(&mut d, last - 1);
    assert_eq!(outcome(&mut d, &older), UpdateOutcome::TooOld);
    // A frame whose samples left the 320 ms buffer long ago.
    let ancient = part(&mut d, 0);
    assert_eq!(outcome(&mut d, &ancient), UpdateOutcome::TooOld);
    // A frame id never issued, and a known id with the wrong trigger time.
    let HostToCore::Correspondences(mut c) = part(&mut d, last) else {
        unreachable!()
    };
    c.frame_id += 1000;
    assert_eq!(
        outcome(&mut d, &HostToCore::Correspondences(c.clone())),
        UpdateOutcome::UnknownFrame
    );
    c.frame_id -= 1000;
    c.trigger_us += 1;
    assert_eq!(
        outcome(&mut d, &HostToCore::Correspondences(c)),
        UpdateOutcome::UnknownFrame
    );
    assert_eq!(d.device.counters().parts_refused, 5);
}

#[test]
fn bad_correspondences_are_rejected_one_by_one_without_touching_the_state() {
    let sc = scenario(ModelKind::Gyro);
    let mut d = tracking(&sc, 3.0);
    d.answer_frames = false;
    let (pred, truth) = next_prediction(&mut d);
    let good = d.observe(&truth);
    let before = d.device.filter().clone();
    // Behind the camera: the model point mirrored through the camera centre.
    let (c_w, _) = sc.mount.camera_pose(&truth);
    let mut behind = good[0];
    for k in 0..3 {
        behind.m_w[k] = (2.0 * c_w[k] - good[0].m_w[k] as f64) as f32;
    }
    // An outlier: registered 100 px away from where the model point is.
    let mut outlier = good[1];
    outlier.m_n[0] += 100.0 / sc.camera.fx as f32;
    let c = Correspondences::split(pred.frame_id, pred.t_us, &[behind, outlier])
        .unwrap()
        .next()
        .unwrap();
    let report = report_in(d.send(&HostToCore::Correspondences(c)));
    assert_eq!((report.accepted, report.rejected), (0, 2));
    // Behind the camera: f32::MAX on the wire, never an infinity (issue 55, point 11).
    assert!(report.residuals[0] == f32::MAX && report.residuals[1] > sc.config.gate);
    let counters = d.device.counters();
    assert_eq!((counters.behind_camera, counters.gated), (1, 1));
    assert_eq!(d.device.filter(), &before);
    // A covariance that is not positive semi-definite is an invalid message.
    let mut bad = good[2];
    bad.cov_n = [1e-6, 1e-3, 1e-6];
    let c = Correspondences::split(pred.frame_id, pred.t_us, &[bad])
        .unwrap()
        .next()
        .unwrap();
    assert_eq!(
        errors_in(&d.send(&HostToCore::Correspondences(c))),
        [ErrorCode::Invalid(InvalidField::CorrespondenceCovariance {
            index: 0
        })]
    );
}

#[test]
fn dead_reckoning_through_a_blind_stretch_then_tracking_again() {
    let mut sc = scenario(ModelKind::Acc);
    sc.blind = vec![(8.0, 8.5)];
    let mut d = Driver::<f64>::new(&sc);
    let mut worst_blind: f64 = 0.0;
    while d.k < d.samples() {
        d.step();
        let (truth, _) = d.last.unwrap();
        if truth.t > 8.0 && truth.t < 8.6 {
            worst_blind = worst_blind.max(errors::position(&d.device, &truth));
        }
    }
    let modes: Vec<_> = d.out.statuses.iter().map(|s| (s.mode, s.reason)).collect();
    assert!(
        modes.contains(&(Mode::DeadReckoning, StatusReason::NoVision)),
        "{modes:?}"
    );
    assert_eq!(
        modes.last(),
        Some(&(Mode::Tracking, StatusReason::VisionAccepted))
    );
    assert!(!modes.iter().any(|m| m.0 == Mode::Diverged), "{modes:?}");
    println!(
        "worst position error over 0.5 s without vision: {:.1} mm",
        worst_blind * 1e3
    );
    assert!(worst_blind < 0.05);
}

#[test]
fn divergence_is_detected_and_the_core_reinitialises_and_recovers() {
    // At 8 s the model no longer matches the scene by 30 cm: every correspondence disagrees
    // with the current estimate.
    let (sc, shifted) = with_model_moved();
    let mut d = Driver::<f64>::new(&sc);
    while d.k < 8 * 200 {
        d.step();
    }
    let n_before = d.out.reports.len();
    let mut shifted_driver = d.switch_scenario(&shifted);
    while shifted_driver.k < 12 * 200 {
        shifted_driver.step();
    }
    let _ = n_before;
    let modes: Vec<_> = shifted_driver
        .out
        .statuses
        .iter()
        .map(|s| (s.mode, s.reason))
        .collect();
    assert!(
        modes.contains(&(Mode::Diverged, StatusReason::ResidualLowpass)),
        "{modes:?}"
    );
    assert!(
        modes.contains(&(Mode::Reinitialising, StatusReason::ResidualLowpass)),
        "{modes:?}"
    );
    assert!(shifted_driver.device.counters().divergences >= 1);
    // Re-initialised from the last good position, it tracks the shifted model again: in the
    // model's frame the camera is now 30 cm further along y.
    while shifted_driver.k < 20 * 200 {
        shifted_driver.step();
    }
    assert_eq!(shifted_driver.device.mode(), Mode::Tracking);
    let (truth, _) = shifted_driver.last.unwrap();
    let p = shifted_driver
        .device
        .filter()
        .st
        .v3(fusion_core::state::POS);
    let offset = Vector3::new(p[0], p[1], p[2]) - truth.p_w;
    assert!(
        (offset - shifted.model_offset).norm() < 0.03,
        "offset {offset}"
    );
}

/// A short burst of wrong correspondences (0.2 s against a model moved by 30 cm) fires the
/// residual monitor; vision was accepted a moment ago, so the core keeps its estimate and only
/// restarts the covariance (soft re-initialisation, no still window) and tracks again as soon
/// as the correspondences are right.
#[test]
fn a_short_divergence_after_good_vision_is_a_soft_reinitialisation() {
    let (sc, shifted) = with_model_moved();
    let d = tracking(&sc, 8.0);
    let before = d.out.statuses.len();
    let mut bad = d.switch_scenario(&shifted);
    while bad.k < (8.2 * 200.0) as usize {
        bad.step();
    }
    let mut d = bad.switch_scenario(&sc);
    while d.k < 10 * 200 {
        d.step();
    }
    let after: Vec<_> = d.out.statuses[before..]
        .iter()
        .map(|s| (s.t_us as f64 * 1e-6, s.mode, s.reason))
        .collect();
    println!("{after:?}");
    let diverged = after
        .iter()
        .position(|s| (s.1, s.2) == (Mode::Diverged, StatusReason::ResidualLowpass))
        .expect("divergence detected");
    // Straight back to dead reckoning from the kept estimate: no still window.
    assert_eq!(
        (
            after[diverged + 1].1,
            after[diverged + 2].1,
            after[diverged + 2].2
        ),
        (
            Mode::Reinitialising,
            Mode::DeadReckoning,
            StatusReason::InitComplete
        ),
        "{after:?}"
    );
    assert!(
        !after.iter().any(|s| s.1 == Mode::Initialising),
        "{after:?}"
    );
    // Tracking again within 0.3 s of the good correspondences coming back, and accurate.
    let back = after
        .iter()
        .rev()
        .find(|s| s.1 == Mode::Tracking)
        .expect("tracking again");
    assert!(back.0 < 8.5, "tracking again only at {:.2} s", back.0);
    assert_eq!(d.device.mode(), Mode::Tracking);
    let (truth, _) = d.last.unwrap();
    let p = d.device.filter().st.v3(fusion_core::state::POS);
    let err = (Vector3::new(p[0], p[1], p[2]) - truth.p_w).norm();
    assert!(err < 0.01, "position error {err}");
}

/// After a soft re-initialisation the gate is wide, and outliers pass it by chance: a part
/// most of whose correspondences fail the gate is withheld whole, the few that passed with it
/// (docs/FILTER.md §7), and the state stays as it was. A part that agrees with the state is
/// applied and the core tracks again, after which parts are judged one correspondence at a
/// time as before.
#[test]
fn after_a_soft_reinitialisation_a_part_that_mostly_fails_the_gate_is_withheld() {
    let (sc, shifted) = with_model_moved();
    let d = tracking(&sc, 8.0);
    let before = d.out.statuses.len();
    let mut bad = d.switch_scenario(&shifted);
    while !bad.out.statuses[before..]
        .iter()
        .any(|s| s.mode == Mode::DeadReckoning && s.reason == StatusReason::InitComplete)
    {
        assert!(bad.k < 10 * 200, "no soft re-initialisation");
        bad.step();
    }
    let mut d = bad.switch_scenario(&sc);
    d.answer_frames = false;
    // Two good correspondences among eight registered 100 px off.
    let (pred, truth) = next_prediction(&mut d);
    let good = d.observe(&truth);
    assert!(good.len() >= 10, "{} correspondences", good.len());
    let mut items = good[..10].to_vec();
    for c in &mut items[2..] {
        c.m_n[0] += 100.0 / sc.camera.fx as f32;
    }
    let filter = d.device.filter().clone();
    let withheld = d.device.counters().withheld;
    let part = Correspondences::split(pred.frame_id, pred.t_us, &items)
        .unwrap()
        .next()
        .unwrap();
    let report = report_in(d.send(&HostToCore::Correspondences(part)));
    let passed = report
        .residuals
        .iter()
        .filter(|&&s| s <= sc.config.gate)
        .count();
    assert!((1..=2).contains(&passed), "{:?}", report.residuals);
    assert_eq!((report.accepted, report.rejected), (0, 10));
    assert_eq!(d.device.counters().withheld, withheld + passed as u32);
    assert_eq!(d.device.filter(), &filter, "the withheld part left a trace");
    assert_ne!(d.device.mode(), Mode::Tracking);
    // The next frame's correspondences are right: applied, and tracking again.
    let (pred, truth) = next_prediction(&mut d);
    let good = d.observe(&truth);
    let part = Correspondences::split(pred.frame_id, pred.t_us, &good)
        .unwrap()
        .next()
        .unwrap();
    let report = report_in(d.send(&HostToCore::Correspondences(part)));
    assert!(
        report.accepted as usize > good.len().min(16) / 2,
        "{report:?}"
    );
    assert_eq!(d.device.mode(), Mode::Tracking);
}

#[test]
fn corrupted_bytes_are_reported_and_the_stream_goes_on() {
    let mut io = DeviceIo::<f32>::new();
    let mut replies = Vec::new();
    let mut buf = [0u8; MAX_FRAME_LEN];
    let hello = encode_frame(&samples::host_messages()[0].1, &mut buf)
        .unwrap()
        .to_vec();
    let mut bad = hello.clone();
    // One bit flipped inside the frame, never into a 0 (the frame delimiter would split it
    // in two: 4.0's version bytes made 0x04 ^ 0x04 one).
    bad[3] ^= if bad[3] == 0x01 { 0x02 } else { 0x01 };
    assert_ne!(bad[3], 0);
    let mut stream = bad;
    stream.extend([0x11, 0x22, 0x00]);
    stream.extend(&hello);
    // Byte by byte, as from a UART.
    for b in &stream {
        io.receive(std::slice::from_ref(b), &mut |frame| {
            replies.push(frame.to_vec())
        });
    }
    let msgs: Vec<CoreToHost> = replies
        .iter()
        .map(|f| {
            protocol::Decoder::new()
                .feed::<CoreToHost>(f)
                .next()
                .unwrap()
                .unwrap()
        })
        .collect();
    assert_eq!(msgs.len(), 3);
    assert!(
        matches!(msgs[0], CoreToHost::Error(e) if e.code == ErrorCode::Decode(DecodeError::Crc))
    );
    assert!(matches!(msgs[1], CoreToHost::Error(e) if matches!(e.code, ErrorCode::Decode(_))));
    assert!(matches!(msgs[2], CoreToHost::HelloAck(_)));
    assert_eq!(io.device.counters().decode_errors, 2);
}

#[test]
fn a_lost_part_does_not_lose_the_parts_that_arrived() {
    let mut sc = scenario(ModelKind::Acc);
    sc.max_correspondences = 40; // three parts per frame
    let mut d = tracking(&sc, 3.0);
    d.answer_frames = false;
    let mut preds = Vec::new();
    while preds.len() < 2 {
        let msg = d.next_imu();
        for a in d.send(&msg) {
            if let CoreToHost::PosePrediction(p) = a {
                preds.push((p, d.last.unwrap().0));
            }
        }
    }
    // Frame A: parts 0 and 2 arrive, part 1 is lost. Frame B arrives complete.
    let (pa, ta) = preds[0];
    let ca = d.observe(&ta);
    let parts: Vec<_> = Correspondences::split(pa.frame_id, pa.t_us, &ca)
        .unwrap()
        .collect();
    assert_eq!(parts.len(), 3);
    let live_before = d.device.filter().clone();
    d.send(&HostToCore::Correspondences(parts[0].clone()));
    d.send(&HostToCore::Correspondences(parts[2].clone()));
    // Incomplete: not yet propagated to the present.
    assert_eq!(d.device.filter(), &live_before);
    let (pb, tb) = preds[1];
    let cb = d.observe(&tb);
    for p in Correspondences::split(pb.frame_id, pb.t_us, &cb).unwrap() {
        d.send(&HostToCore::Correspondences(p));
    }
    // Frame B's arrival flushed frame A's two parts first, then applied B.
    assert_ne!(d.device.filter(), &live_before);
    let applied = d
        .out
        .reports
        .iter()
        .filter(|r| r.outcome == UpdateOutcome::Applied)
        .count();
    assert!(applied >= 2 + cb.len().div_ceil(16));
}
