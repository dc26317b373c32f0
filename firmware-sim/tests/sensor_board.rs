//! Issue 36, on the PC: a scenario's IMU through the simulated ICM-42688-P and the board's
//! sample path into the core, in core-sampled mode. Time stamps against the truth, every
//! injected fault counted and reported, the drift measured, and the filter fed exactly what
//! the core reports it took.

use firmware_sim::sim::scenario::{Scenario, ScenarioName, simulate_imu};
use firmware_sim::sim::sensor_board::{BoardRun, Faults, odr_for, run};
use fusion_core::Device;
use icm42688::Settings;
use protocol::{
    CoreToHost, GapCause, HostToCore, ImuSample, SampleSource, Sampling, SamplingEvent,
    SamplingReport,
};

const TRIGGER_EVERY: u16 = 4;

fn device() -> Device<f32> {
    let mut d = Device::new();
    d.set_onboard_imu(true);
    let mut send = |m: HostToCore| d.handle(&m, &mut |_| {});
    send(HostToCore::Hello(protocol::Hello {
        version: protocol::PROTOCOL_VERSION,
    }));
    send(HostToCore::Configure(protocol::samples::config()));
    send(HostToCore::Sampling(Sampling {
        source: SampleSource::Core {
            trigger_every: TRIGGER_EVERY,
        },
        raw_imu: true,
    }));
    send(HostToCore::Init(protocol::Init {
        position: [0.0, 0.0, 0.0],
        attitude: protocol::InitAttitude::Gravity,
    }));
    d
}

fn simulate(seconds: f64, settings: Option<Settings>, faults: &Faults) -> (BoardRun, Device<f32>) {
    let sc = Scenario::new(ScenarioName::DesktopFast)
        .with_duration(seconds)
        .unwrap();
    let readings = simulate_imu(&sc, 7);
    let odr = odr_for(sc.imu.rate_hz).expect("the part has the scenario's rate");
    let settings = settings.unwrap_or(Settings::new(odr));
    let mut d = device();
    let r = run(&readings, settings, faults, &mut d, |_, _, _| {}).unwrap();
    // Every sample was accepted by the filter: in time order, within range. (Without vision
    // the filter only dead-reckons here, so its accuracy is not judged.)
    let refused: Vec<_> = r
        .sent
        .iter()
        .filter(|m| matches!(m, CoreToHost::Error(_)))
        .collect();
    assert!(refused.is_empty(), "{refused:?}");
    assert_eq!(d.counters().imu_time_rejected, 0);
    (r, d)
}

fn raw(r: &BoardRun) -> Vec<ImuSample> {
    r.sent
        .iter()
        .filter_map(|m| match m {
            CoreToHost::RawImu(s) => Some(*s),
            _ => None,
        })
        .collect()
}

fn triggers(sent: &[CoreToHost]) -> Vec<protocol::Trigger> {
    sent.iter()
        .filter_map(|m| match m {
            CoreToHost::Trigger(t) => Some(*t),
            _ => None,
        })
        .collect()
}

fn reports(r: &BoardRun) -> Vec<SamplingReport> {
    r.sent
        .iter()
        .filter_map(|m| match m {
            CoreToHost::Sampling(s) => Some(*s),
            _ => None,
        })
        .collect()
}

/// Each stamped sample's error against the truth [µs], the sample found by nearest time.
fn stamp_errors(r: &BoardRun) -> Vec<(usize, u64)> {
    raw(r)
        .iter()
        .map(|s| {
            let k = r
                .sampled_at_us
                .partition_point(|&t| t < s.t_us)
                .min(r.sampled_at_us.len() - 1);
            let k =
                if k > 0 && s.t_us - r.sampled_at_us[k - 1] < r.sampled_at_us[k].abs_diff(s.t_us) {
                    k - 1
                } else {
                    k
                };
            (k, r.sampled_at_us[k].abs_diff(s.t_us))
        })
        .collect()
}

#[test]
fn every_sample_is_stamped_within_a_microsecond_and_every_fourth_triggers_the_camera() {
    let (r, d) = simulate(5.0, None, &Faults::default());
    let errors = stamp_errors(&r);
    assert_eq!(
        errors.len(),
        r.sampled_at_us.len(),
        "every sample reaches the core"
    );
    let worst = errors.iter().map(|e| e.1).max().unwrap();
    println!("{} samples, worst stamp error {worst} µs", errors.len());
    assert!(worst <= 1, "worst stamp error {worst} µs");
    // One trigger message per pulse, every 4th sample, frame ids from 0.
    let triggers = triggers(&r.sent);
    assert_eq!(triggers.len() as u32, r.trigger_pulses);
    assert_eq!(triggers.len(), r.sampled_at_us.len().div_ceil(4));
    for (i, t) in triggers.iter().enumerate() {
        assert_eq!(t.frame_id, i as u32);
        assert!(t.t_us.abs_diff(r.sampled_at_us[i * 4]) <= 1);
    }
    let last = d.onboard_state().report();
    assert_eq!((last.lost, last.part_resets, last.late_reads), (0, 0, 0));
}

#[test]
fn clock_drift_is_measured_and_the_batched_stamps_corrected() {
    let faults = Faults {
        drift_ppm: 300.0,
        irq_latency_us: 0,
        ..Faults::default()
    };
    // Ten samples per interrupt: nine of them stamped back by the FIFO's time stamps.
    let mut settings = Settings::new(icm42688::Odr::Hz100);
    settings.watermark = 10;
    settings.interrupt = icm42688::Interrupt::Watermark;
    let (r, d) = simulate(20.0, Some(settings), &faults);
    let drift = d.onboard_state().report().drift_ppm;
    println!("drift measured {drift} ppm (injected 300)");
    assert!((drift - 300.0).abs() <= 2.0, "{drift}");
    // Once measured (the first window is 4 s), every stamp within 1 µs.
    let errors = stamp_errors(&r);
    let settled: Vec<_> = errors.iter().filter(|(k, _)| *k >= 1000).collect();
    let worst = settled.iter().map(|e| e.1).max().unwrap();
    let worst_before = errors.iter().map(|e| e.1).max().unwrap();
    println!("worst stamp error {worst} µs once measured, {worst_before} µs before");
    assert!(worst <= 1, "{worst}");
}

fn gaps(r: &BoardRun) -> Vec<protocol::SampleGap> {
    reports(r)
        .iter()
        .filter_map(|s| match s.event {
            SamplingEvent::Gap(g) => Some(g),
            _ => None,
        })
        .collect()
}

#[test]
fn a_fifo_overflow_is_counted_exactly_and_marked() {
    // The MCU serves nothing for 1.5 s: the FIFO (128 samples) overflows.
    let faults = Faults {
        busy: Some((200, 350)),
        ..Faults::default()
    };
    let (r, d) = simulate(5.0, None, &faults);
    assert!(r.dropped_on_overflow > 0);
    let g = gaps(&r);
    assert_eq!(g.len(), 1, "{g:?}");
    assert_eq!(g[0].cause, GapCause::FifoOverflow);
    assert_eq!(u64::from(g[0].lost), r.dropped_on_overflow);
    assert_eq!(
        raw(&r).len() as u64 + r.dropped_on_overflow,
        r.sampled_at_us.len() as u64
    );
    assert_eq!(
        u64::from(d.onboard_state().report().lost),
        r.dropped_on_overflow
    );
    // The samples after it are stamped right again.
    assert!(stamp_errors(&r).iter().all(|e| e.1 <= 1));
}

#[test]
fn a_corrupt_packet_is_dropped_with_its_read_counted_and_marked() {
    let faults = Faults {
        corrupt_at: Some(100),
        ..Faults::default()
    };
    let (r, _) = simulate(3.0, None, &faults);
    let g = gaps(&r);
    assert_eq!(g.len(), 1, "{g:?}");
    assert_eq!(g[0].cause, GapCause::CorruptPacket);
    assert_eq!(g[0].lost as usize + raw(&r).len(), r.sampled_at_us.len());
}

#[test]
fn missed_interrupts_lose_nothing_and_are_counted() {
    let faults = Faults {
        missed_interrupts: vec![50, 51, 120],
        ..Faults::default()
    };
    let (r, d) = simulate(3.0, None, &faults);
    assert!(gaps(&r).is_empty());
    assert_eq!(raw(&r).len(), r.sampled_at_us.len());
    assert_eq!(d.onboard_state().report().late_reads, 2);
    assert!(stamp_errors(&r).iter().all(|e| e.1 <= 1));
}

#[test]
fn a_part_reset_is_found_repaired_and_its_gap_marked() {
    let faults = Faults {
        reset_at: Some(150),
        ..Faults::default()
    };
    let (r, d) = simulate(4.0, None, &faults);
    let report = d.onboard_state().report();
    assert_eq!(report.part_resets, 1);
    let g = gaps(&r);
    assert_eq!(g.len(), 1, "{g:?}");
    assert_eq!(g[0].cause, GapCause::PartReset);
    assert_eq!(g[0].lost as usize + raw(&r).len(), r.sampled_at_us.len());
    // Found within the check interval (100 ms = 10 samples), and sampling goes on.
    assert!(g[0].lost <= 11, "{g:?}");
    assert!(stamp_errors(&r).iter().all(|e| e.1 <= 1));
}

/// Quantiles (0.5, 0.9, 0.99) and the largest of `v` [µs].
fn spread(mut v: Vec<i64>) -> (i64, i64, i64, i64) {
    v.sort_unstable_by_key(|e| e.abs());
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize].abs();
    (q(0.5), q(0.9), q(0.99), q(1.0))
}

/// Issue 55, point 5: the pulse left the main loop 0 to ~4 ms after the sample whose time
/// the `Trigger` carries. Now a timer armed for the predicted time of the due sample raises it:
/// simulated against the main loop's timing (turns of 20 µs, 5 % of them up to 4 ms, or 30 %
/// up to 12 ms; interrupt latency 0-1 µs), every timer pulse rises within 10 µs of its trigger's time stamp and of the
/// sample's true time; the first after the choice (nothing to predict from) fires at the read.
#[test]
fn the_trigger_rises_within_10_us_of_its_sample_whatever_the_main_loop_does() {
    use firmware_sim::sim::sensor_board::{LoopModel, run_loop};
    let sc = Scenario::new(ScenarioName::DesktopFast)
        .with_duration(30.0)
        .unwrap();
    let readings = simulate_imu(&sc, 7);
    let settings = Settings::new(odr_for(sc.imu.rate_hz).unwrap());
    for model in [
        LoopModel {
            seed: 1,
            short_us: 20,
            long_share: 0.05,
            long_max_us: 4_000,
            irq_jitter_us: 1,
            drift_ppm: 0.0,
        },
        LoopModel {
            seed: 2,
            short_us: 20,
            long_share: 0.3,
            long_max_us: 12_000,
            irq_jitter_us: 1,
            drift_ppm: 0.0,
        },
        // The internal oscillator at its tolerance's edges, from the first trigger on.
        LoopModel {
            seed: 3,
            short_us: 20,
            long_share: 0.05,
            long_max_us: 4_000,
            irq_jitter_us: 1,
            drift_ppm: 20_000.0,
        },
        LoopModel {
            seed: 4,
            short_us: 20,
            long_share: 0.05,
            long_max_us: 4_000,
            irq_jitter_us: 1,
            drift_ppm: -20_000.0,
        },
    ] {
        let mut d = device();
        let r = run_loop(&readings, settings, &model, &mut d).unwrap();
        let triggers = triggers(&r.sent);
        // Every pulse has its trigger, in order, and the camera's count is the core's.
        assert_eq!(triggers.len(), r.rises.len());
        assert!(
            triggers
                .iter()
                .enumerate()
                .all(|(i, t)| t.frame_id == i as u32)
        );
        let half = u64::from(settings.period_us()) / 2;
        let truth = |t_us: u64| {
            let k = r.sampled_at_us.partition_point(|&s| s + half < t_us);
            r.sampled_at_us[k.min(r.sampled_at_us.len() - 1)]
        };
        let mut to_stamp = Vec::new();
        let mut to_truth = Vec::new();
        let mut fired_now = 0;
        for (t, &(rise, now)) in triggers.iter().zip(&r.rises) {
            if now {
                fired_now += 1;
                continue;
            }
            to_stamp.push(rise as i64 - t.t_us as i64);
            to_truth.push(rise as i64 - truth(t.t_us) as i64);
        }
        let at_read: Vec<i64> = r.reads.iter().map(|&(read, s)| (read - s) as i64).collect();
        let (s50, s90, s99, smax) = spread(to_stamp);
        let (t50, t90, t99, tmax) = spread(to_truth);
        let (r50, r90, r99, rmax) = spread(at_read);
        println!(
            "loop of {} µs turns, {:.0} % up to {} µs, IMU {:+} ppm: {} triggers ({fired_now} fired at the read, \
             the first); timer pulse to its stamp p50/p90/p99/max {s50}/{s90}/{s99}/{smax} µs, to \
             the sample's true time {t50}/{t90}/{t99}/{tmax} µs; a pulse fired at the read \
             (before issue 55) would have been {r50}/{r90}/{r99}/{rmax} µs late",
            model.short_us,
            model.long_share * 100.0,
            model.long_max_us,
            model.drift_ppm,
            triggers.len()
        );
        assert_eq!(fired_now, 1);
        assert!(smax <= 10 && tmax <= 10, "{smax} / {tmax} µs");
        // One every fourth sample, but where the loop came too late to arm the due one.
        assert!(
            triggers.len() >= readings.len() / 4 - 10,
            "{}",
            triggers.len()
        );
    }
}
