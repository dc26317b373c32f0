//! The core's own IMU (protocol 3.1, protocol/PROTOCOL.md §7) through the device loop: who
//! samples, the triggers, the raw stream and the reports; and a board's samples run the
//! filter exactly as the host's.

use fusion_core::Device;
use fusion_core::onboard::OnboardEvent;
use protocol::{
    CoreToHost, ErrorCode, GapCause, HostToCore, ImuSample, SampleGap, SampleSource, Sampling,
    SamplingEvent,
};

fn send(d: &mut Device<f32>, m: &HostToCore) -> Vec<CoreToHost> {
    let mut got = Vec::new();
    d.handle(m, &mut |a| got.push(a));
    got
}

fn onboard(d: &mut Device<f32>, e: OnboardEvent) -> Vec<CoreToHost> {
    let mut got = Vec::new();
    d.onboard(&e, &mut |a| got.push(a));
    got
}

fn started(d: &mut Device<f32>) {
    send(
        d,
        &HostToCore::Hello(protocol::Hello {
            version: protocol::PROTOCOL_VERSION,
        }),
    );
    send(d, &HostToCore::Configure(protocol::samples::config()));
    send(
        d,
        &HostToCore::Init(protocol::Init {
            position: [0.0, 0.0, 1.0],
            attitude: protocol::InitAttitude::GravityAndYaw(0.0),
        }),
    );
}

fn core_sampling(trigger_every: u16, raw_imu: bool) -> HostToCore {
    HostToCore::Sampling(Sampling {
        source: SampleSource::Core { trigger_every },
        raw_imu,
    })
}

/// A moving sample `k` at 100 Hz (the sample configuration's rate), a trigger every 4th.
fn sample(k: u64) -> ImuSample {
    let t = k as f32 * 0.01;
    ImuSample {
        t_us: 1_000_000 + k * 10_000,
        gyro: [0.2 * t.sin(), -0.1, 0.3 * (2.0 * t).cos()],
        accel: [0.5 * t.cos(), 0.2, 9.81 - 0.3 * t.sin()],
        trigger: k.is_multiple_of(4),
    }
}

#[test]
fn a_core_without_an_imu_refuses_to_sample_and_keeps_taking_the_hosts_samples() {
    let mut d = Device::<f32>::new();
    started(&mut d);
    let got = send(&mut d, &core_sampling(4, false));
    assert!(
        matches!(
            &got[..],
            [CoreToHost::Error(e)] if e.code == ErrorCode::NoOnboardImu
        ),
        "{got:?}"
    );
    assert!(!d.onboard_state().core_samples());
    // The board's samples are not used, the host's are (the still window of 50, then the
    // filter runs).
    for k in 0..60 {
        assert!(onboard(&mut d, OnboardEvent::Sample(sample(k))).is_empty());
    }
    assert_eq!(d.counters().imu_applied, 0);
    for k in 0..60 {
        let got = send(&mut d, &HostToCore::Imu(sample(k)));
        assert!(!got.iter().any(|m| matches!(m, CoreToHost::Error(_))));
    }
    assert_eq!(d.counters().imu_applied, 10);
}

#[test]
fn raw_imu_is_refused_while_the_host_samples() {
    let mut d = Device::<f32>::new();
    d.set_onboard_imu(true);
    started(&mut d);
    let got = send(
        &mut d,
        &HostToCore::Sampling(Sampling {
            source: SampleSource::Host,
            raw_imu: true,
        }),
    );
    assert!(
        matches!(&got[..], [CoreToHost::Error(e)]
            if e.code == ErrorCode::Invalid(protocol::InvalidField::Sampling)),
        "{got:?}"
    );
    let got = send(&mut d, &core_sampling(1001, false));
    assert!(matches!(&got[..], [CoreToHost::Error(_)]), "{got:?}");
}

/// The same samples, from the host as `Imu` messages and from the board as onboard events:
/// the same filter, state for state, and the same predictions; the board's run sends a
/// `Trigger` per trigger, numbered from 0, beside each prediction of the same time stamp.
#[test]
fn a_boards_samples_run_the_filter_exactly_as_the_hosts() {
    let mut host = Device::<f32>::new();
    started(&mut host);
    let mut board = Device::<f32>::new();
    board.set_onboard_imu(true);
    started(&mut board);
    let got = send(&mut board, &core_sampling(4, true));
    assert!(
        matches!(&got[..], [CoreToHost::Sampling(r)] if r.event == SamplingEvent::Started),
        "{got:?}"
    );
    // The host's own samples are refused now, and change nothing.
    let got = send(&mut board, &HostToCore::Imu(sample(0)));
    assert!(
        matches!(&got[..], [CoreToHost::Error(e)] if e.code == ErrorCode::HostImuWhileCoreSamples)
    );

    let mut triggers = 0;
    for k in 0..300 {
        let s = sample(k);
        let from_host = send(&mut host, &HostToCore::Imu(s));
        let from_board = onboard(&mut board, OnboardEvent::Sample(s));
        let mut rest = from_board.iter().peekable();
        // Raw sample first, then the trigger, then any report, then the filter's answers.
        assert_eq!(rest.next(), Some(&CoreToHost::RawImu(s)));
        if s.trigger {
            assert_eq!(
                rest.next(),
                Some(&CoreToHost::Trigger(protocol::Trigger {
                    frame_id: triggers,
                    t_us: s.t_us
                }))
            );
            triggers += 1;
        }
        if let Some(CoreToHost::Sampling(r)) = rest.peek() {
            assert_eq!(r.event, SamplingEvent::Periodic);
            assert_eq!(r.samples, k as u32 + 1);
            rest.next();
        }
        let filter_answers: Vec<_> = rest.cloned().collect();
        assert_eq!(filter_answers, from_host, "sample {k}");
        assert_eq!(host.filter(), board.filter(), "sample {k}");
    }
    assert_eq!(triggers, 75);
    assert_eq!(board.onboard_state().report().samples, 300);
    assert!(board.counters().predictions > 0);
    assert_eq!(board.counters().predictions, host.counters().predictions);
}

#[test]
fn gaps_and_faults_are_counted_and_reported() {
    let mut d = Device::<f32>::new();
    d.set_onboard_imu(true);
    started(&mut d);
    send(&mut d, &core_sampling(0, false));
    // Through the still window (50 samples): the filter runs.
    for k in 0..60 {
        onboard(&mut d, OnboardEvent::Sample(sample(k)));
    }
    let gap = SampleGap {
        from_us: sample(59).t_us,
        to_us: sample(64).t_us,
        lost: 4,
        cause: GapCause::FifoOverflow,
    };
    let got = onboard(&mut d, OnboardEvent::Gap(gap));
    assert!(
        matches!(&got[..], [CoreToHost::Sampling(r)]
            if r.event == SamplingEvent::Gap(gap) && r.lost == 4),
        "{got:?}"
    );
    onboard(&mut d, OnboardEvent::PartReset);
    onboard(&mut d, OnboardEvent::LateRead);
    onboard(&mut d, OnboardEvent::Drift(250.0));
    onboard(&mut d, OnboardEvent::Drift(f32::NAN));
    let r = d.onboard_state().report();
    assert_eq!(
        (r.lost, r.part_resets, r.late_reads, r.drift_ppm),
        (4, 1, 1, 250.0)
    );
    // The filter integrated across the gap: the next sample is applied.
    let before = d.counters().imu_applied;
    onboard(&mut d, OnboardEvent::Sample(sample(64)));
    assert_eq!(d.counters().imu_applied, before + 1);
    // Back to the host: the board's samples are dropped, the host's taken.
    let got = send(
        &mut d,
        &HostToCore::Sampling(Sampling {
            source: SampleSource::Host,
            raw_imu: false,
        }),
    );
    assert!(
        matches!(&got[..], [CoreToHost::Sampling(r)] if r.event == SamplingEvent::Stopped),
        "{got:?}"
    );
    assert!(onboard(&mut d, OnboardEvent::Sample(sample(65))).is_empty());
    assert_eq!(d.counters().imu_applied, before + 1);
}
