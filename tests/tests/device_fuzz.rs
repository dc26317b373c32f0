//! No input panics the core: a running device (f32 and f64) fed a mix of its normal session
//! and random messages of every kind with arbitrary field values (random postcard bodies that
//! happen to decode), then random bytes through the framed byte interface.

use std::cell::Cell;

use fusion_core::device::MAX_TIME_UPDATES_PER_MESSAGE;
use fusion_core::{Device, DeviceIo, Kernels};
use proptest::test_runner::TestCaseError;
use protocol::{CoreToHost, HostToCore, Mode, ModelKind};
use tests::harness::{Driver, Scenario, scenes};

/// Small deterministic generator (xorshift64*).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn bytes(&mut self, max: usize) -> Vec<u8> {
        let n = (self.next() % max as u64) as usize;
        (0..n).map(|_| self.next() as u8).collect()
    }
}

/// A random message of any kind, or `None` when the random body does not decode.
fn random_message(rng: &mut Rng) -> Option<HostToCore> {
    let mut body = rng.bytes(400);
    if let Some(first) = body.first_mut() {
        *first %= 6; // a valid variant index, so that every kind comes up
    }
    postcard::from_bytes::<HostToCore>(&body).ok()
}

fn run<T: Kernels>(model: ModelKind, seed: u64) -> (usize, Mode) {
    let sc = scenes::standard(model, 12.0, 2.0, seed);
    let mut d = Driver::<T>::new(&sc);
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let mut injected = 0;
    while d.k < d.samples() {
        d.step();
        // After the start, now and then a burst of random messages of any kind.
        if d.k > 400 && rng.next().is_multiple_of(2) {
            for _ in 0..1 + rng.next() % 8 {
                if let Some(msg) = random_message(&mut rng) {
                    // Reconfiguring or re-initialising at random is part of the test, but
                    // keep the session alive often enough to reach the deep paths.
                    if matches!(msg, HostToCore::Configure(_) | HostToCore::Reset)
                        && !rng.next().is_multiple_of(4)
                    {
                        continue;
                    }
                    d.send(&msg);
                    injected += 1;
                }
            }
        }
    }
    (injected, d.device.mode())
}

#[test]
fn random_messages_into_a_running_core_never_panic() {
    let mut total = 0;
    for (i, model) in ModelKind::INERTIAL.into_iter().enumerate() {
        let (a, mode_a) = run::<f32>(model, 100 + i as u64);
        let (b, mode_b) = run::<f64>(model, 200 + i as u64);
        println!(
            "{model:?}: {a} + {b} random messages injected; final modes {mode_a:?}, {mode_b:?}"
        );
        total += a + b;
    }
    assert!(
        total > 3000,
        "the generator must produce messages ({total})"
    );
}

#[test]
fn random_bytes_into_the_framed_interface_never_panic() {
    let mut io = DeviceIo::<f32>::new();
    let mut rng = Rng(0xDEAD_BEEF);
    let mut replies = 0usize;
    for _ in 0..20_000 {
        let chunk = rng.bytes(300);
        io.receive(&chunk, &mut |_| replies += 1);
    }
    println!(
        "{replies} replies to 20000 random chunks; {:?}",
        io.device.counters()
    );
    assert!(io.device.counters().decode_errors > 0);
    let _ = Device::<f64>::new();
}

/// One step of the work-bound property test.
#[derive(Clone, Debug)]
enum Op {
    /// A sample (or tick) this long after the last one sent [µs].
    After { dt_us: u64, trigger: bool },
    /// A sample (or tick) at any time.
    At { t_us: u64, trigger: bool },
    /// `Resume` at any time.
    Resume(u64),
    /// `Resume` this long after the last sample sent [µs].
    ResumeAfter(u64),
    /// `Init` again.
    Init,
    /// Answers the `age`-th newest prediction with correspondences that agree with it, the
    /// image points moved by `offset` (normalised units).
    Answer { age: usize, offset: f32 },
    /// `Query`.
    Query,
}

fn op() -> impl proptest::strategy::Strategy<Value = Op> {
    use proptest::prelude::*;
    prop_oneof![
        6 => (prop_oneof![3 => 1u64..20_000, 1 => 0u64..3_000_000], any::<bool>())
            .prop_map(|(dt_us, trigger)| Op::After { dt_us, trigger }),
        1 => (any::<u64>(), any::<bool>()).prop_map(|(t_us, trigger)| Op::At { t_us, trigger }),
        1 => (u64::MAX - 10..=u64::MAX, any::<bool>())
            .prop_map(|(t_us, trigger)| Op::At { t_us, trigger }),
        1 => any::<u64>().prop_map(Op::Resume),
        1 => (0u64..3_000_000).prop_map(Op::ResumeAfter),
        1 => Just(Op::Init),
        3 => (0usize..4, -0.001f32..0.001).prop_map(|(age, offset)| Op::Answer { age, offset }),
        1 => Just(Op::Query),
    ]
}

/// Correspondences of the wall's points in front of a predicted camera, at the predicted pose
/// (image points moved by `offset`), at most 40.
fn agreeing(p: &protocol::PosePrediction, offset: f32) -> Vec<protocol::Correspondence> {
    use nalgebra::{Quaternion, UnitQuaternion, Vector3};
    let q_cw = UnitQuaternion::from_quaternion(Quaternion::new(
        p.q_cw[0], p.q_cw[1], p.q_cw[2], p.q_cw[3],
    ));
    let c_w = Vector3::from(p.c_w);
    scenes::wall()
        .iter()
        .filter_map(|m| {
            let m_w = m.cast::<f32>();
            let pc = q_cw * (m_w - c_w);
            (pc[2] > 0.1).then(|| protocol::Correspondence {
                m_n: [pc[0] / pc[2] + offset, pc[1] / pc[2] - offset],
                cov_n: [1e-6, 0.0, 1e-6],
                m_w: [m_w[0], m_w[1], m_w[2]],
                cov_w: [1e-6, 0.0, 0.0, 1e-6, 0.0, 1e-6],
            })
        })
        .take(40)
        .collect()
}

/// Every other correspondence as a contour along a fixed oblique normal through its point.
fn as_points_and_contours(
    corrs: Vec<protocol::Correspondence>,
) -> (Vec<protocol::Correspondence>, Vec<protocol::ContourPoint>) {
    let (mut points, mut contours) = (Vec::new(), Vec::new());
    for (i, c) in corrs.into_iter().enumerate() {
        if i % 2 == 0 {
            points.push(c);
        } else {
            let n = [0.6, 0.8];
            contours.push(protocol::ContourPoint {
                m_w: c.m_w,
                cov_w: c.cov_w,
                n,
                d: n[0] * c.m_n[0] + n[1] * c.m_n[1],
                var_d: c.cov_n[0],
            });
        }
    }
    (points, contours)
}

/// The most time updates one message ran, all of them, messages sent, correspondences
/// applied.
type Tally = Cell<(u32, u64, u64, u64)>;

/// The clock message of `model` at `t_us`: an IMU sample where the model has an IMU, a tick
/// otherwise.
fn clock(model: ModelKind, t_us: u64, trigger: bool) -> HostToCore {
    if model.has_imu() {
        HostToCore::Imu(protocol::ImuSample {
            t_us,
            gyro: [0.01, -0.02, 0.0],
            accel: [0.1, 0.0, 9.81],
            trigger,
        })
    } else {
        HostToCore::Tick(protocol::Tick { t_us, trigger })
    }
}

/// A `Resume` at `t_us` from the scenario's initial position, moving slowly.
fn resume(sc: &Scenario, t_us: u64) -> HostToCore {
    HostToCore::Resume(protocol::Resume {
        t_us,
        s_w: sc.init.position,
        q_sw: [1.0, 0.0, 0.0, 0.0],
        v_w: [0.1, 0.0, 0.0],
        a_w: [0.0; 3],
        omega_s: [0.0; 3],
        gyro_bias: [0.0; 3],
        accel_bias: [0.0; 3],
    })
}

/// The messages that `op` sends, given the time of the last sample sent (`last`, moved on
/// where the op sets it) and the predictions received so far.
fn messages(
    op: &Op,
    model: ModelKind,
    sc: &Scenario,
    last: &mut u64,
    predictions: &[protocol::PosePrediction],
) -> Result<Vec<HostToCore>, String> {
    Ok(match *op {
        Op::After { dt_us, trigger } => {
            *last = last.saturating_add(dt_us);
            vec![clock(model, *last, trigger)]
        }
        Op::At { t_us, trigger } => {
            *last = t_us;
            vec![clock(model, t_us, trigger)]
        }
        Op::Resume(t_us) | Op::ResumeAfter(t_us) => {
            // A host that resumes at any time goes on from there; one resumed after
            // its last sample goes on before the resumed time.
            let t_us = match op {
                Op::ResumeAfter(_) => last.saturating_add(t_us),
                _ => {
                    *last = t_us;
                    t_us
                }
            };
            vec![resume(sc, t_us)]
        }
        Op::Init => vec![HostToCore::Init(sc.init)],
        Op::Answer { age, offset } => match predictions.iter().rev().nth(age) {
            Some(p) => {
                // Every other one as a contour (protocol 3.2): parts of both kinds.
                let (points, contours) = as_points_and_contours(agreeing(p, offset));
                protocol::frame_messages(p.frame_id, p.t_us, &points, &contours)
                    .map_err(|e| format!("{e:?}"))?
                    .collect()
            }
            None => Vec::new(),
        },
        Op::Query => vec![HostToCore::Query],
    })
}

/// Sends `msg`, keeping the predictions it brings, and tallies the time updates it ran; an
/// error when they are more than `MAX_TIME_UPDATES_PER_MESSAGE`.
fn send_counted<T: Kernels>(
    d: &mut Driver<T>,
    msg: &HostToCore,
    predictions: &mut Vec<protocol::PosePrediction>,
    tally: &Tally,
) -> Result<(), String> {
    let before = d.device.counters().time_updates;
    for a in d.send(msg) {
        if let CoreToHost::PosePrediction(p) = a {
            predictions.push(p);
        }
    }
    let work = d.device.counters().time_updates - before;
    if work > MAX_TIME_UPDATES_PER_MESSAGE {
        return Err(format!("{work} time updates for {msg:?}"));
    }
    let (max, total, sent, applied) = tally.get();
    tally.set((max.max(work), total + u64::from(work), sent + 1, applied));
    Ok(())
}

/// One case of the work-bound test: a running core of `model` gets the messages of `ops`,
/// each checked against the bound and tallied, then the correspondences it applied.
fn case<T: Kernels>(model: ModelKind, ops: &[Op], tally: &Tally) -> Result<(), String> {
    let mut sc = scenes::standard(model, 2.0, 2.0, 1);
    // A short still window, so that a sequence's `Init`s leave it running most of the time.
    sc.config.still_samples = 5;
    let mut d = Driver::<T>::new(&sc);
    // Running: past the still window.
    while d.k < 150 {
        d.step();
    }
    let mut last = tests::harness::t_us(d.k - 1, sc.imu_rate_hz);
    let warm = d.device.counters().accepted;
    let mut predictions = Vec::new();
    for op in ops {
        let msgs = messages(op, model, &sc, &mut last, &predictions)?;
        for msg in msgs {
            send_counted(&mut d, &msg, &mut predictions, tally)?;
        }
    }
    let (max, total, sent, applied) = tally.get();
    let accepted = u64::from(d.device.counters().accepted - warm);
    tally.set((max, total, sent, applied + accepted));
    Ok(())
}

/// Issue 32, defect 1: one message's work is bounded whatever its time stamps say. A running
/// core (each model's clock message, f32 and f64) gets random sequences of samples (some any
/// `u64` time, some up to 3 s after the last), `Resume`s at any time, `Init`s, queries and
/// answers to its predictions that it applies (so frames are re-propagated through the sample
/// ring). No message runs more than `MAX_TIME_UPDATES_PER_MESSAGE` time updates. (Before the
/// fix, `Resume { t_us: 0 }` and a sample at `u64::MAX` integrated 9.2·10¹⁴ steps.)
#[test]
fn no_message_costs_more_than_a_fixed_number_of_time_updates() {
    use proptest::test_runner::{Config, TestRunner};

    let tally = Tally::default();
    let mut runner = TestRunner::new(Config {
        cases: 64,
        failure_persistence: None,
        ..Config::default()
    });
    let strategy = proptest::collection::vec(op(), 1..200);
    for model in [ModelKind::Acc, ModelKind::Vision] {
        runner
            .run(&strategy, |ops| {
                case::<f32>(model, &ops, &tally).map_err(TestCaseError::fail)?;
                case::<f64>(model, &ops, &tally).map_err(TestCaseError::fail)?;
                Ok(())
            })
            .unwrap();
    }
    let (max, total, sent, applied) = tally.get();
    println!(
        "{sent} messages: at most {max} time updates for one (bound \
         {MAX_TIME_UPDATES_PER_MESSAGE}), {total} in all; {applied} correspondences applied"
    );
    // The sequences reach the paths that do the work: integration and re-propagation.
    assert!(
        total > 1_000 && max >= 40 && applied > 1_000,
        "{max}, {total}, {applied}"
    );
}
