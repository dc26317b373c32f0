//! The whole host pipeline per frame, at 320×240 and 640×480, on a short synthetic desktop-fast
//! sequence, the frames decoded beforehand: undistort, render at the predicted pose, FAST on demand, pyramids, KLT of 40
//! features, correspondences; and the link: from sending a camera trigger to the last update
//! report of the frame's 40 correspondences (prediction back, correspondences out, update
//! applied at the trigger time), over the pty pair to the simulated board, with the trigger →
//! prediction part printed.
//!
//! `cargo bench -p host-vision --bench pipeline` (the datasets are synthesised on first use
//! into `target/bench-data`). After each resolution the mean time per stage is printed. The
//! registrations run on rayon's pool: `RAYON_NUM_THREADS=1` gives the one-thread figure.

use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use firmware_sim::sim::scenario::ScenarioName;
use frames::euroc::Dataset;
use host_vision::synth::{FrameOptions, SynthOptions};
use host_vision::track::vision::{
    FrameImage, FrameJob, StageTimes, Vision, VisionOptions, prediction_pose,
};
use host_vision::track::{CoreLink, Incoming, LinkSpec};
use nalgebra::Vector3;
use protocol::{
    CoreToHost, Correspondence, Correspondences, HostToCore, Init, InitAttitude, PosePrediction,
};
use tracker::Precision;

fn dataset(w: u32, h: u32) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../target/bench-data")
        .join(format!("desktop-fast-{w}x{h}"));
    if !dir.join("manifest.json").exists() {
        let options = SynthOptions {
            duration: Some(2.0),
            frames: FrameOptions::new(w, h),
            overwrite: true,
            ..SynthOptions::new(ScenarioName::DesktopFast, dir.clone())
        };
        host_vision::synth::run(&options, &mut |_, _| {}).expect("synthesise the bench dataset");
    }
    dir
}

/// Predictions from the ground truth, as a well-tracking core would send them.
fn jobs(ds: &Dataset) -> Vec<FrameJob> {
    ds.triggers()
        .into_iter()
        .filter_map(|(f, k)| {
            let (p, q) = ds.groundtruth_at(ds.imu[k].stamp)?;
            let (c_w, q_cw) = ds.hand_eye.camera_pose(&p, &q);
            let q = q_cw.quaternion();
            Some(FrameJob {
                index: f,
                stamp: ds.frames[f].stamp,
                // Decoded beforehand: the host frame's figure excludes file decoding (a
                // camera or video hands over pixels).
                image: FrameImage::Decoded(
                    image::open(&ds.frames[f].path)
                        .expect("bench frame")
                        .to_luma8(),
                ),
                prediction: PosePrediction {
                    frame_id: f as u32,
                    t_us: (ds.imu[k].stamp - ds.imu[0].stamp) / 1000,
                    c_w: [c_w.x as f32, c_w.y as f32, c_w.z as f32],
                    q_cw: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
                    cov: [0.0; 21],
                },
                keep_image: false,
                omega_c: None,
            })
        })
        .collect()
}

/// CPU time the process has used so far, all threads (lavapipe's included), in seconds: utime
/// and stime of `/proc/self/stat`, in the kernel's USER_HZ of 100 ticks a second. `None` off
/// Linux.
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The fields after the command's closing parenthesis; utime and stime are the 12th and
    // 13th of them.
    let rest = &stat[stat.rfind(')')? + 2..];
    let mut fields = rest.split_whitespace().skip(11);
    let utime: f64 = fields.next()?.parse().ok()?;
    let stime: f64 = fields.next()?.parse().ok()?;
    Some((utime + stime) / 100.0)
}

fn pipeline(c: &mut Criterion) {
    println!(
        "kernels: {} copy (TRACKER_ISA=baseline runs the baseline's)",
        isa::name()
    );
    for (w, h) in [(320, 240), (640, 480)] {
        let dir = dataset(w, h);
        let ds = Dataset::open(&dir).expect("bench dataset");
        let model = host_vision::model::load(&dir.join("model/scene.obj")).expect("model");
        let mut vision = Vision::new(ds.camera.camera, &model, VisionOptions::default())
            .expect("renderer (WGPU_BACKEND=vulkan with Mesa's lavapipe)");
        let jobs = jobs(&ds);
        let mut k = 0usize;
        let mut sum = StageTimes::default();
        let mut n = 0usize;
        let mut registered = 0usize;
        let mut coverage = 0.0;
        let cpu_before = process_cpu_seconds();
        c.bench_function(&format!("host_frame_{w}x{h}_40_features"), |b| {
            b.iter(|| {
                let job = jobs[k % jobs.len()].clone();
                k += 1;
                let r = vision.process(job).expect("frame");
                let t = r.times;
                sum.load += t.load;
                sum.render += t.render;
                sum.extract += t.extract;
                sum.pyramids += t.pyramids;
                sum.klt += t.klt;
                sum.total += t.total;
                registered += r.correspondences.len();
                coverage += r.model_coverage;
                n += 1;
                black_box(r.correspondences.len())
            })
        });
        let cpu = cpu_before.zip(process_cpu_seconds()).map(|(a, b)| b - a);
        let ms = |v: f64| 1e3 * v / n as f64;
        if n == 0 {
            continue;
        }
        println!(
            "{w}x{h} per frame over {n} frames ({} threads): undistort {:.2} ms, render {:.2} ms, FAST on demand {:.2} ms, pyramids {:.2} ms, KLT {:.2} ms ({:.1} registered), total {:.2} ms; model on {:.0} % of the image",
            rayon::current_num_threads(),
            ms(sum.load),
            ms(sum.render),
            ms(sum.extract),
            ms(sum.pyramids),
            ms(sum.klt),
            registered as f64 / n as f64,
            ms(sum.total),
            100.0 * coverage / n as f64
        );
        // What the frame costs the machine, whatever the load: the time of every thread,
        // over the same frames (criterion's own analysis adds about 1 %).
        if let Some(cpu) = cpu {
            println!(
                "{w}x{h} CPU time per frame, all threads (the renderer's included): {:.2} ms",
                ms(cpu)
            );
        }
    }
}

fn recv_until<F: FnMut(&CoreToHost) -> bool>(link: &CoreLink, mut done: F) {
    loop {
        match link.recv(Duration::from_secs(5)).expect("core answers") {
            Incoming::Message(m) if done(&m) => return,
            _ => {}
        }
    }
}

/// The next pose prediction from the core.
fn next_prediction(link: &CoreLink) -> PosePrediction {
    let mut pred = None;
    recv_until(link, |m| match m {
        CoreToHost::PosePrediction(p) => {
            pred = Some(*p);
            true
        }
        _ => false,
    });
    pred.expect("a prediction")
}

fn link(c: &mut Criterion) {
    let mut link = CoreLink::open(&LinkSpec::Sim(Precision::F32)).expect("pty pair");
    link.send(&HostToCore::Hello(protocol::Hello {
        version: protocol::PROTOCOL_VERSION,
    }))
    .unwrap();
    recv_until(&link, |m| matches!(m, CoreToHost::HelloAck(_)));
    let mut config = protocol::samples::config();
    config.state_every = 0;
    config.still_samples = 10;
    // The first benchmark sends no vision: keep the core from declaring the growing
    // covariance a divergence meanwhile.
    config.divergence.covariance_frobenius = 1e12;
    link.send(&HostToCore::Configure(config)).unwrap();
    link.send(&HostToCore::Init(Init {
        position: [0.0, 0.0, 1.0],
        attitude: InitAttitude::GravityAndYaw(0.0),
    }))
    .unwrap();
    let mut t_us = 0u64;
    let mut imu = |trigger: bool| {
        t_us += 10_000;
        HostToCore::Imu(protocol::ImuSample {
            t_us,
            gyro: [0.0; 3],
            accel: [0.0, 0.0, 9.81],
            trigger,
        })
    };
    for _ in 0..20 {
        link.send(&imu(false)).unwrap();
    }
    link.send(&imu(true)).unwrap();
    let p = next_prediction(&link);
    // 40 points 2 m in front of the predicted camera, consistent with it.
    let pose = prediction_pose(&p).expect("a valid prediction");
    let items: Vec<Correspondence> = (0..40)
        .map(|i| {
            let p_c = Vector3::new((i % 8) as f64 * 0.2 - 0.7, (i / 8) as f64 * 0.2 - 0.4, 2.0);
            let m_w = pose.camera_to_world(&p_c);
            protocol::samples::correspondence(
                [(p_c.x / p_c.z) as f32, (p_c.y / p_c.z) as f32],
                [m_w.x as f32, m_w.y as f32, m_w.z as f32],
            )
        })
        .collect();
    let (mut to_prediction, mut count) = (Duration::ZERO, 0u32);
    c.bench_function("link_trigger_to_applied_update_40_pty", |b| {
        b.iter(|| {
            let start = std::time::Instant::now();
            link.send(&imu(true)).unwrap();
            let p = next_prediction(&link);
            to_prediction += start.elapsed();
            count += 1;
            let parts: Vec<Correspondences> = Correspondences::split(p.frame_id, p.t_us, &items)
                .unwrap()
                .collect();
            let expected = parts.len();
            for part in parts {
                link.send(&HostToCore::Correspondences(part)).unwrap();
            }
            let mut reports = 0;
            recv_until(&link, |m| {
                if let CoreToHost::UpdateReport(r) = m {
                    assert_eq!(r.outcome, protocol::UpdateOutcome::Applied);
                    reports += 1;
                }
                reports == expected
            });
        })
    });
    println!(
        "of which trigger to prediction: {:.1} µs (mean of {count})",
        to_prediction.as_secs_f64() * 1e6 / count.max(1) as f64
    );
    let _ = link.close();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(Duration::from_secs(5));
    targets = pipeline, link
}
criterion_main!(benches);
