//! Issue 36 end to end on the PC: the hand-held scenario of the harness (200 Hz IMU, 25 Hz
//! camera, 60 ms latency) with the core sampling a simulated ICM-42688-P through the board's
//! sample path, against the host-driven replay of the same samples, and against today's
//! host-driven run of the unquantised readings.

use icm42688::{Odr, Settings};
use protocol::ModelKind;
use tests::board::Board;
use tests::harness::{Driver, errors, scenes};

const SECONDS: f64 = 20.0;

fn position_errors(errs: &[f64]) -> (f64, f64) {
    let mean = errs.iter().sum::<f64>() / errs.len() as f64;
    (mean, errs.iter().cloned().fold(0.0, f64::max))
}

#[test]
fn the_core_sampling_its_own_imu_tracks_as_the_host_driven_replay_of_its_samples() {
    let sc = scenes::standard(ModelKind::Acc, SECONDS, 2.0, 11);
    // The board: the part at 200 Hz, a trigger every 8th sample (the scenario's camera).
    let mut board_run = Driver::<f32>::new(&sc);
    let mut board = Board::start(Settings::new(Odr::Hz200), &mut board_run, 8);
    let mut board_errors = Vec::new();
    let mut states = Vec::new();
    for _ in 0..board_run.samples() {
        board.step(&mut board_run);
        let truth = board_run.last.unwrap().0;
        board_errors.push(errors::position(&board_run.device, &truth));
        states.push(board_run.device.filter().clone());
    }
    // Every sample stamped at its time exactly (no drift, no latency here), none lost.
    assert_eq!(board.raw.len(), board_run.samples());
    for (k, s) in board.raw.iter().enumerate() {
        assert_eq!(
            s.t_us,
            tests::harness::t_us(k, sc.imu_rate_hz),
            "sample {k}"
        );
    }
    // The host-driven replay of the samples the core reported taking: the same filter,
    // state for state.
    let mut replay = Driver::<f32>::new(&sc);
    for (k, s) in board.raw.iter().enumerate() {
        replay.step_with(*s);
        assert_eq!(replay.device.filter(), &states[k], "sample {k}");
    }
    // Today's host-driven run of the unquantised readings: the same accuracy.
    let mut host_run = Driver::<f32>::new(&sc);
    let mut host_errors = Vec::new();
    for _ in 0..host_run.samples() {
        host_run.step();
        host_errors.push(errors::position(
            &host_run.device,
            &host_run.last.unwrap().0,
        ));
    }
    let settle = board_errors.len() / 10;
    let (board_mean, board_max) = position_errors(&board_errors[settle..]);
    let (host_mean, host_max) = position_errors(&host_errors[settle..]);
    println!(
        "position error after the first 10 %: core-sampled mean {:.2} mm max {:.2} mm; \
         host-driven mean {:.2} mm max {:.2} mm",
        board_mean * 1e3,
        board_max * 1e3,
        host_mean * 1e3,
        host_max * 1e3
    );
    assert!(tests::harness::tracking_at_end(&board_run.device));
    assert!(
        board_mean < host_mean * 1.2 + 1e-3,
        "{board_mean} vs {host_mean}"
    );
    assert_eq!(board_run.out.errors, vec![]);
}

/// Every fault of the simulated part, injected into a tracked run: the samples lost are
/// counted and reported with their cause, the gaps marked, and the filter tracks through.
#[test]
fn faults_of_the_part_are_reported_and_the_filter_tracks_through_them() {
    use protocol::{GapCause, Mode, SamplingEvent};
    use tests::board::Serve;
    let sc = scenes::standard(ModelKind::Acc, SECONDS, 2.0, 12);
    let mut d = Driver::<f32>::new(&sc);
    let mut board = Board::start(Settings::new(Odr::Hz200), &mut d, 8);
    let at = |s: f64| (s * sc.imu_rate_hz) as usize;
    let mut worst = 0.0f64;
    for k in 0..d.samples() {
        if k == at(8.0) {
            board.reset_part();
        }
        if k == at(11.0) {
            board.corrupt_next();
        }
        // Two samples marked invalid, the first the newest of a read (issue 55, point 6).
        if k == at(16.0) + 1 {
            board.invalid_next(2);
        }
        let serve = if (at(5.0)..at(5.8)).contains(&k) {
            Serve::Nothing // 160 samples: the FIFO (128) overflows
        } else if [at(13.0), at(13.0) + 1, at(14.0), at(16.0)].contains(&k) {
            Serve::MissedInterrupt
        } else if k == at(15.0) {
            Serve::Nothing
        } else if k == at(15.0) + 1 {
            // Issue 55, point 4: an interrupt inside the read, its sample in it or not.
            Serve::ArrivedDuringRead
        } else if k == at(15.5) {
            Serve::NextArrivesAfterRead
        } else {
            Serve::Interrupt
        };
        board.step_faulty(&mut d, serve);
        // While the MCU is busy the filter stands at the last sample it had, while the truth
        // moves on: judged from a second after it has caught up.
        if k > at(2.0) && !(at(5.0)..at(6.8)).contains(&k) {
            worst = worst.max(errors::position(&d.device, &d.last.unwrap().0));
        }
    }
    let report = d.device.onboard_state().report();
    let gaps: Vec<_> = d
        .out
        .sampling
        .iter()
        .filter_map(|r| match r.event {
            SamplingEvent::Gap(g) => Some(g),
            _ => None,
        })
        .collect();
    println!("sampling at the end: {report:?}");
    println!("gaps: {gaps:?}");
    println!(
        "worst position error after 2 s (outside the busy stretch): {:.1} mm",
        worst * 1e3
    );
    let causes: Vec<_> = gaps.iter().map(|g| g.cause).collect();
    assert_eq!(
        causes,
        [
            GapCause::FifoOverflow,
            GapCause::PartReset,
            GapCause::CorruptPacket,
            GapCause::InvalidSample
        ]
    );
    let invalid = gaps[3];
    let t = |k: usize| board.raw[0].t_us + 5_000 * k as u64;
    assert_eq!(invalid.lost, 2);
    assert!(invalid.from_us.abs_diff(t(at(16.0))) <= 1, "{invalid:?}");
    assert!(invalid.to_us.abs_diff(t(at(16.0) + 3)) <= 1, "{invalid:?}");
    // Every sample at its own time (to the stamps' 1.07 µs tick), whatever the loop's timing:
    // an interrupt inside a read, a missed one, an invalid newest sample, polling.
    // Consecutive samples are whole periods apart, one unless samples were lost between.
    let mut missing = 0;
    for (i, pair) in board.raw.windows(2).enumerate() {
        let d = pair[1].t_us - pair[0].t_us;
        let n = (d + 2_500) / 5_000;
        assert!(
            n >= 1 && d.abs_diff(n * 5_000) <= 2,
            "samples {i} and {} stamped {d} µs apart",
            i + 1
        );
        missing += n - 1;
    }
    assert_eq!(missing, u64::from(report.lost));
    // Nothing lost silently: every sample is either taken or counted lost.
    assert_eq!(report.lost as usize + board.raw.len(), d.samples());
    assert_eq!(report.lost, gaps.iter().map(|g| g.lost).sum::<u32>());
    // Late reads: the three missed interrupts, the read after the busy stretch, and the one
    // served late with an interrupt inside it.
    assert_eq!((report.part_resets, report.late_reads), (1, 5));
    assert!(d.out.errors.is_empty(), "{:?}", d.out.errors);
    assert!(
        !d.out.statuses.iter().any(|s| s.mode == Mode::Diverged),
        "{:?}",
        d.out.statuses
    );
    assert!(tests::harness::tracking_at_end(&d.device));
    assert!(worst < 0.03, "{worst}");
}

/// Issue 55, point 9: an IMU that failed to start at boot (off the bus: WHO_AM_I reads 0xFF) left
/// the core answering `NoOnboardImu` for good. The path tries it again every second: once the
/// part answers, the core samples it.
#[test]
fn an_imu_that_failed_to_start_is_tried_again() {
    use firmware_sim::sim::sensor_board::{NoDelay, SharedPart, TriggerLine};
    use icm42688::Icm42688;
    use protocol::{ErrorCode, HostToCore, SampleSource, Sampling};
    use sample_path::{At, START_RETRY_US, SamplePath};
    let sc = scenes::standard(ModelKind::Acc, 2.0, 2.0, 3);
    let mut d = Driver::<f32>::new(&sc);
    let part = SharedPart::default();
    part.part().set_unplugged(true);
    let mut path = SamplePath::new(
        Icm42688::new(part.clone(), Settings::new(Odr::Hz200)),
        TriggerLine::default(),
    );
    assert!(path.start(0, &mut NoDelay).is_err());
    d.device.set_onboard_imu(path.started());
    let sampling = HostToCore::Sampling(Sampling {
        source: SampleSource::Core { trigger_every: 8 },
        raw_imu: true,
    });
    let refused = |answers: &[protocol::CoreToHost]| {
        answers.iter().any(
            |a| matches!(a, protocol::CoreToHost::Error(e) if e.code == ErrorCode::NoOnboardImu),
        )
    };
    assert!(refused(&d.send(&sampling)));
    let mut sent = Vec::new();
    // Still wrong a second later: tried, refused again.
    let poll = |path: &mut SamplePath<_, _>, d: &mut Driver<'_, f32>, t, sent: &mut Vec<_>| {
        path.poll(&mut At(t), &mut d.device, &mut NoDelay, &mut |m| {
            sent.push(m)
        })
    };
    assert!(poll(&mut path, &mut d, START_RETRY_US, &mut sent).is_err());
    assert!(!path.started());
    // The part answers (it was powered late): within a second the core has its IMU.
    part.part().set_unplugged(false);
    assert!(poll(&mut path, &mut d, START_RETRY_US + 500_000, &mut sent).is_ok());
    assert!(!path.started());
    assert!(poll(&mut path, &mut d, 2 * START_RETRY_US, &mut sent).is_ok());
    assert!(path.started());
    assert!(!refused(&d.send(&sampling)));
}
