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
    let triggers: Vec<_> = r
        .sent
        .iter()
        .filter_map(|m| match m {
            CoreToHost::Trigger(t) => Some(*t),
            _ => None,
        })
        .collect();
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
