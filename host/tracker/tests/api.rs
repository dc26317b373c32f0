//! Bad input through the `Tracker` API gets a typed error, never a panic (issue 34): an image
//! of another size than the camera's, time going backwards, a frame pushed to a tracker that
//! never finished starting (or stopped), and a closed transport.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use camera::{Camera, CameraPose, Pinhole, pinhole_camera};
use image::GrayImage;
use nalgebra::Vector3;
use protocol::HostToCore;
use tracker::{
    CoreTransport, Frame, InProcessCore, Incoming, Start, State, Tracker, TrackerConfig,
    TrackerError,
};

fn camera() -> Camera {
    pinhole_camera(320, 240, Pinhole::new(300.0, 300.0, 160.0, 120.0)).unwrap()
}

/// The tracker at a given pose over the standard test scene, with the in-process core.
fn config(cache: &std::path::Path) -> TrackerConfig {
    let mut c = TrackerConfig::new(camera(), 30.0, cache.to_owned());
    c.start = Start::Camera(
        CameraPose::look_at(
            Vector3::new(1.2, -1.2, 1.0),
            Vector3::new(0.0, 0.0, 0.2),
            Vector3::z(),
        )
        .unwrap(),
    );
    c.timeout = Duration::from_secs(5);
    // The tests read the run's record, kept from the events.
    c.details = true;
    c
}

fn inproc() -> InProcessCore {
    InProcessCore::default()
}

fn frame(index: usize, t_ms: i64, width: u32, height: u32) -> Frame {
    let image = GrayImage::from_fn(width, height, |x, y| {
        image::Luma([((x * 7 + y * 3) % 251) as u8])
    });
    Frame::decoded(index, t_ms * 1_000_000, image)
}

#[test]
fn an_image_of_another_size_than_the_camera_is_refused_and_tracking_goes_on() {
    let cache = tempfile::tempdir().unwrap();
    let model = model::procedural::test_scene();
    let mut t = Tracker::new(config(cache.path()), &model, inproc()).unwrap();
    assert_eq!(t.state(), State::Starting);
    let err = t.push_frame(frame(0, 0, 640, 480)).unwrap_err();
    assert!(
        matches!(
            err,
            TrackerError::ImageSize {
                index: 0,
                width: 640,
                height: 480,
                camera_width: 320,
                camera_height: 240
            }
        ),
        "{err:?}"
    );
    assert_eq!(
        err.to_string(),
        "frame 0: the image is 640x480 pixels, the camera's are 320x240"
    );
    // The next frame of the right size is tracked as usual; the refused one is reported.
    t.push_frame(frame(1, 33, 320, 240)).unwrap();
    let events: Vec<_> = t.poll().collect();
    assert!(
        events
            .iter()
            .any(|e| matches!(e, tracker::Event::FrameSkipped { index: 0, .. }))
    );
    assert!(
        events
            .iter()
            .any(|e| matches!(e, tracker::Event::Frame(r) if r.index == 1))
    );
    let done = t.finish();
    done.result.unwrap();
    let mut record = tracker::record::Record::default();
    record.observe_all(events.iter().chain(&done.events));
    assert_eq!(record.frame_errors.len(), 1);
}

#[test]
fn time_going_backwards_is_refused_with_both_times() {
    let cache = tempfile::tempdir().unwrap();
    let model = model::procedural::test_scene();
    let mut t = Tracker::new(config(cache.path()), &model, inproc()).unwrap();
    t.push_frame(frame(0, 1_000, 320, 240)).unwrap();
    t.push_frame(frame(1, 1_033, 320, 240)).unwrap();
    for (index, t_ms) in [(2, 1_033), (3, 1_010), (4, 0)] {
        let err = t.push_frame(frame(index, t_ms, 320, 240)).unwrap_err();
        match err {
            TrackerError::TimeBackwards {
                what,
                t_us,
                previous_us,
            } => {
                assert_eq!(what, format!("frame {index}"));
                assert_eq!(t_us, (t_ms - 1_000) * 1_000);
                assert_eq!(previous_us, 33_000);
            }
            other => panic!("{other:?}"),
        }
    }
    // The clock goes on from the last frame taken.
    t.push_frame(frame(5, 1_066, 320, 240)).unwrap();
    t.finish().result.unwrap();
}

/// A `Tracker` exists only once `Tracker::new` has finished (the handshake, the core's
/// configuration and its initialisation): there is nothing to push a frame to before, which
/// the compiler checks (the `compile_fail` example on [`Tracker`]). A tracker whose start
/// failed is an error instead; one that stopped on an error refuses every later frame with
/// why it stopped.
#[test]
fn a_tracker_that_did_not_start_or_stopped_takes_no_frame() {
    let cache = tempfile::tempdir().unwrap();
    // No texture: the tracker cannot start, and says why.
    let mut model = model::procedural::test_scene();
    for m in &mut model.materials {
        m.texture = None;
    }
    let err = Tracker::new(config(cache.path()), &model, inproc())
        .err()
        .unwrap();
    assert!(matches!(err, TrackerError::Untextured), "{err:?}");
    // A frame rate of zero cannot clock the core.
    let mut bad = config(cache.path());
    bad.frame_rate_hz = 0.0;
    let err = Tracker::new(bad, &model::procedural::test_scene(), inproc())
        .err()
        .unwrap();
    assert!(matches!(err, TrackerError::Config(_)), "{err:?}");
}

/// A transport whose line can be cut from outside, as a pulled cable does.
struct Cuttable {
    link: InProcessCore,
    cut: Arc<AtomicBool>,
}

impl CoreTransport for Cuttable {
    fn name(&self) -> &str {
        "cuttable"
    }

    fn send(&mut self, msg: &HostToCore) -> Result<(), TrackerError> {
        if self.cut.load(Ordering::Relaxed) {
            return Err(TrackerError::Link("link cuttable is down".into()));
        }
        self.link.send(msg)
    }

    fn recv_within(&mut self, timeout: Duration) -> Result<Option<Incoming>, TrackerError> {
        if self.cut.load(Ordering::Relaxed) {
            return Err(TrackerError::Link("link cuttable is down".into()));
        }
        self.link.recv_within(timeout)
    }

    fn reconnect(&mut self) -> Result<(), TrackerError> {
        Err(TrackerError::Link("link cuttable stays down".into()))
    }
}

#[test]
fn a_closed_transport_stops_the_tracker_with_a_link_error() {
    let cache = tempfile::tempdir().unwrap();
    let model = model::procedural::test_scene();
    // Closed before the start: the handshake fails.
    let cut = Arc::new(AtomicBool::new(true));
    let closed = Cuttable {
        link: inproc(),
        cut: cut.clone(),
    };
    let err = Tracker::new(config(cache.path()), &model, closed)
        .err()
        .unwrap();
    assert!(matches!(err, TrackerError::Link(_)), "{err:?}");
    // Closed while tracking: the frame fails with the link's error, later frames are refused
    // with it, and what was tracked is kept.
    cut.store(false, Ordering::Relaxed);
    let open = Cuttable {
        link: inproc(),
        cut: cut.clone(),
    };
    let mut t = Tracker::new(config(cache.path()), &model, open).unwrap();
    t.push_frame(frame(0, 0, 320, 240)).unwrap();
    cut.store(true, Ordering::Relaxed);
    let err = t.push_frame(frame(1, 33, 320, 240)).unwrap_err();
    assert!(matches!(err, TrackerError::Link(_)), "{err:?}");
    let err = t.push_frame(frame(2, 66, 320, 240)).unwrap_err();
    match &err {
        TrackerError::Stopped(why) => assert!(why.contains("link cuttable is down"), "{why}"),
        other => panic!("{other:?}"),
    }
    let done = t.finish();
    assert!(matches!(done.result, Err(TrackerError::Stopped(_))));
    let mut record = tracker::record::Record::default();
    record.observe_all(&done.events);
    assert_eq!(record.results.len(), 1);
}

#[test]
fn relocate_sends_a_search_at_the_next_frame() {
    let cache = tempfile::tempdir().unwrap();
    let model = model::procedural::test_scene();
    let mut t = Tracker::new(config(cache.path()), &model, inproc()).unwrap();
    t.push_frame(frame(0, 0, 320, 240)).unwrap();
    t.relocate().unwrap();
    assert_eq!(t.state(), State::Lost);
    let mut record = tracker::record::Record::default();
    record.observe_all(&t.poll().collect::<Vec<_>>());
    t.push_frame(frame(1, 33, 320, 240)).unwrap();
    // The search's answer is taken at the next frame in a replay.
    t.push_frame(frame(2, 66, 320, 240)).unwrap();
    let events: Vec<_> = t.poll().collect();
    record.observe_all(&events);
    let located: Vec<_> = events
        .into_iter()
        .filter_map(|e| match e {
            tracker::Event::Located { index, pose } => Some((index, pose)),
            _ => None,
        })
        .collect();
    // A striped synthetic frame holds no model: searched, and nothing found.
    assert_eq!(located, vec![(1, None)]);
    let done = t.finish();
    done.result.unwrap();
    record.observe_all(&done.events);
    assert_eq!(record.recoveries.len(), 1);
}

/// Issue 56: with an IMU the state follows the frames' verdicts, as vision-only: frames that
/// hold no model are never tracked, so the tracker never says "tracking" however the core's
/// filter runs, and is lost half a second after its first frame; every frame it analysed
/// comes with its pose's covariance.
#[test]
fn with_an_imu_frames_never_tracked_never_make_the_state_tracking() {
    let cache = tempfile::tempdir().unwrap();
    let model = model::procedural::test_scene();
    let mut c = config(cache.path());
    c.model = protocol::ModelKind::Acc;
    c.rig = tracker::Rig {
        imu_rate_hz: 200.0,
        imu_noise: None,
        camera_rate_hz: Some(25.0),
        hand_eye: tracker::HandEye::IDENTITY,
    };
    let mut t = Tracker::new(c, &model, inproc()).unwrap();
    let mut states = Vec::new();
    let mut reports = Vec::new();
    // 2 s of an IMU at rest, a frame every 8th sample.
    for k in 0..400u64 {
        let t_ns = k * 5_000_000;
        if k % 8 == 0 {
            t.push_frame(frame((k / 8) as usize, (t_ns / 1_000_000) as i64, 320, 240))
                .unwrap();
        }
        t.push_imu(tracker::ImuSample {
            t_ns,
            gyro: [0.0; 3],
            accel: [0.0, 0.0, 9.81],
        })
        .unwrap();
        states.push(t.state());
        reports.extend(t.poll().filter_map(|e| match e {
            tracker::Event::Frame(f) => Some(f),
            _ => None,
        }));
    }
    assert!(!states.contains(&State::Tracking), "{states:?}");
    assert_eq!(states.last(), Some(&State::Lost));
    assert!(reports.len() > 30, "{} frames reported", reports.len());
    for f in &reports {
        assert_ne!(f.tracked, Some(true), "{f:?}");
        assert_eq!(f.weak, None, "{f:?}");
        if f.pose.is_some() {
            assert!(f.cov.is_some(), "{f:?}");
        }
    }
    t.finish().result.unwrap();
}

/// What the builder is given and the vision-only model cannot use is refused by name when the
/// tracker starts, not dropped.
#[test]
fn the_builder_refuses_imu_settings_without_an_imu() {
    let cache = tempfile::tempdir().unwrap();
    let builder = || {
        tracker::TrackerBuilder::new(camera(), model::procedural::test_scene())
            .cache(cache.path().to_owned())
            .start(config(cache.path()).start)
    };
    let err = builder().latency_s(0.05).build().err().unwrap();
    assert!(
        matches!(&err, TrackerError::Config(m) if m.contains("latency")),
        "{err:?}"
    );
    let on_core = tracker::ImuOnCore::new(4, 200.0);
    let err = builder().imu_on_core(on_core).build().err().unwrap();
    assert!(
        matches!(&err, TrackerError::Config(m) if m.contains("own IMU")),
        "{err:?}"
    );
    // The same builder without them starts.
    assert_eq!(builder().build().unwrap().state(), State::Starting);
}
