//! Live tracking (issue 35): a source that delivers frames faster than the tracker analyses
//! them, read through the capture thread that keeps only the newest ([`frames::live`]).
//! Every frame taken was the newest, the dropped count is the frames never taken, and the
//! poses of a synthetic scene stay on its ground truth.

use std::time::Duration;

use camera::{Camera, CameraPose, Pinhole, pinhole_camera};
use frames::live::{LiveFrames, Paced};
use nalgebra::Vector3;
use render::{RenderView, Renderer};
use tracker::{Answers, Event, Frame, InProcessCore, Start, Tracker, TrackerConfig};

/// The source's frame period [ms]: a thousand frames per second, faster than any analysis
/// here.
const PERIOD_MS: i64 = 1;
const FRAMES: usize = 600;

fn pinhole() -> Pinhole {
    Pinhole::new(300.0, 300.0, 160.0, 120.0)
}

fn camera() -> Camera {
    pinhole_camera(320, 240, pinhole()).unwrap()
}

/// The ground truth at `t` [s]: the camera circling the scene at 20°/s, looking at its centre.
fn truth(t: f64) -> CameraPose {
    let angle = (-45.0f64 + 20.0 * t).to_radians();
    let r = 1.2 * std::f64::consts::SQRT_2;
    CameraPose::look_at(
        Vector3::new(r * angle.cos(), r * angle.sin(), 1.0),
        Vector3::new(0.0, 0.0, 0.2),
        Vector3::z(),
    )
    .unwrap()
}

fn rendered(model: &model::Model) -> Vec<Frame> {
    let mut renderer = Renderer::new(320, 240).unwrap();
    renderer.set_model(model).unwrap();
    (0..FRAMES)
        .map(|i| {
            let t_ms = i as i64 * PERIOD_MS;
            let view = RenderView {
                pinhole: pinhole(),
                pose: truth(t_ms as f64 * 1e-3),
                near: 0.05,
                far: 20.0,
            };
            Frame::decoded(i, t_ms * 1_000_000, renderer.render(&view).unwrap().gray)
        })
        .collect()
}

#[test]
fn a_source_faster_than_the_tracker_is_dropped_never_queued_and_the_poses_stay_true() {
    let cache = tempfile::tempdir().unwrap();
    let model = model::procedural::test_scene();
    let frames = rendered(&model);
    let mut config = TrackerConfig::new(camera(), 1e3 / PERIOD_MS as f64, cache.path().into());
    config.start = Start::Camera(truth(0.0));
    config.answers = Answers::WhenReady;
    config.timeout = Duration::from_secs(5);
    config.details = true;
    let mut record = tracker::record::Record::default();
    let core = InProcessCore::default();
    let mut tracker = Tracker::new(config, &model, core).unwrap();

    let mut live = LiveFrames::start(Paced::new(frames.into_iter().map(Ok::<_, String>))).unwrap();
    let mut reports = Vec::new();
    while let Some(captured) = live.next_frame() {
        let c = captured.unwrap();
        // No frame waits behind another: the one taken is the newest delivered.
        assert_eq!(c.frame.index + 1, c.delivered, "frame {}", c.frame.index);
        tracker.push_frame(c.frame).unwrap();
        for e in tracker.poll() {
            record.observe(&e);
            if let Event::Frame(r) = e {
                reports.push(r);
            }
        }
    }
    let counts = live.counts();
    let done = tracker.finish();
    done.result.unwrap();
    record.observe_all(&done.events);
    let latency = &record.latency;
    println!(
        "{} delivered, {} taken, {} dropped; age when taken: {:?}; capture -> pose: {:?}",
        counts.delivered,
        counts.taken,
        counts.dropped,
        latency.age_taken(),
        latency.capture_to_pose()
    );
    assert_eq!(counts.delivered, FRAMES);
    assert_eq!(counts.taken + counts.dropped, FRAMES);
    assert_eq!(counts.taken, reports.len());
    assert!(
        counts.dropped > counts.taken,
        "{counts:?}: delivered faster than analysed"
    );
    // The tracker counts the same drops from the gaps between the frames' indices.
    assert_eq!(latency.dropped(), counts.dropped);
    assert_eq!(
        latency
            .frames
            .values()
            .map(|f| f.dropped_before)
            .sum::<usize>(),
        counts.dropped
    );

    let mut errors = Vec::new();
    for r in &reports {
        let (Some(pose), Some(true)) = (r.pose, r.tracked) else {
            continue;
        };
        let t = truth(r.index as f64 * PERIOD_MS as f64 * 1e-3);
        let metres = (pose.c_w - t.c_w).norm();
        let degrees = pose.q_cw.angle_to(&t.q_cw).to_degrees();
        errors.push((r.index, metres, degrees));
    }
    println!("tracked frames (index, position error [m], angle error [°]): {errors:?}");
    assert!(
        errors.len() * 10 >= reports.len() * 8,
        "{} of {} frames tracked",
        errors.len(),
        reports.len()
    );
    for &(index, metres, degrees) in &errors {
        assert!(
            metres < 0.01 && degrees < 0.3,
            "frame {index}: {metres} m, {degrees}°"
        );
    }
}
