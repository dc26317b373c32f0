//! End to end, the paper's experiments on synthetic scenarios: `host-vision`'s tracking
//! pipeline (rendering, FAST, photometric KLT, feature map) with the simulated board running
//! `fusion-core` at the other end of a pty pair, as a user runs it (`host-vision track`).
//!
//! The datasets are synthesised once per test process into `CARGO_TARGET_TMPDIR` (at reduced
//! lengths where the scenario allows it). `cargo test --release -p tests --test tracking --
//! --nocapture` prints every figure.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};

use firmware_sim::sim::scenario::ScenarioName;
use frames::euroc::Dataset;
use host_vision::eval::{ensure_dataset, options_for};
use host_vision::track::{self, Faults, Pacing, TrackOptions, TrackRun};
use nalgebra::Vector3;
use protocol::ModelKind;

/// Synthesises `scenario` (first `duration` seconds) once per process.
fn dataset(scenario: ScenarioName, duration: f64) -> PathBuf {
    static LOCK: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());
    let mut done = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let cache = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("tracking-datasets");
    let dir = cache.join(format!("{scenario}-{duration}s-seed0"));
    if !done.contains(&dir) {
        // Fresh data in every test process: a cached dataset of an older generator could hide
        // a change.
        let _ = std::fs::remove_dir_all(&dir);
        let start = std::time::Instant::now();
        let made = ensure_dataset(&cache, scenario, Some(duration), 0, &mut |_, _| {})
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(made, dir);
        println!(
            "synthesised {scenario} ({duration} s) in {:.1} s",
            start.elapsed().as_secs_f64()
        );
        done.push(dir.clone());
    }
    dir
}

fn options(dataset: &std::path::Path, name: &str, model: ModelKind) -> TrackOptions {
    let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("tracking-runs")
        .join(name);
    let mut o = options_for(dataset, out).expect("the synthetic dataset's manifest");
    o.filter = model;
    o.overlay_every = 0;
    // Each test process replaces the runs of the one before.
    o.overwrite = true;
    o
}

fn track(o: &TrackOptions) -> TrackRun {
    let run = track::run(o, Arc::new(AtomicBool::new(false)), &mut |_, _, _, _| {})
        .unwrap_or_else(|e| panic!("tracking {}: {e}", o.out.display()));
    println!("--- {}\n{}", o.out.display(), run.summary);
    run
}

fn mean_px(run: &TrackRun) -> f64 {
    run.summary
        .mean_prediction_error_px
        .expect("some features were registered")
}

/// Tilt error (angle between the true and estimated vertical in the IMU frame) [°] of every
/// state, with its time [s].
fn tilt_errors(dataset: &Dataset, run: &TrackRun) -> Vec<(f64, f64)> {
    let stamp0 = dataset.imu[0].stamp;
    run.log
        .states
        .iter()
        .filter_map(|s| {
            let (_, q_true) = dataset.groundtruth_at(stamp0 + s.t_us * 1000)?;
            let (_, q_est) = track::state_pose(s);
            let up_true = q_true.inverse() * Vector3::z();
            let up_est = q_est.inverse() * Vector3::z();
            Some((s.t_us as f64 * 1e-6, up_true.angle(&up_est).to_degrees()))
        })
        .collect()
}

fn mean_between(series: &[(f64, f64)], t0: f64, t1: f64) -> f64 {
    let v: Vec<f64> = series
        .iter()
        .filter(|(t, _)| *t >= t0 && *t < t1)
        .map(|&(_, e)| e)
        .collect();
    assert!(!v.is_empty(), "no samples in [{t0}, {t1})");
    v.iter().sum::<f64>() / v.len() as f64
}

/// The paper's accuracy bounds for the acc model on the fast desktop sequence: mean position
/// error ≤ 1 cm and each mean Euler angle error ≤ 1° (the paper: 1 cm, [1.0, 0.39, 0.9]°).
fn assert_desktop_fast_accuracy(run: &TrackRun) {
    let a = run.summary.accuracy.expect("ground truth and snap-on");
    assert!(
        a.mean_position_m <= 0.01,
        "mean position error {:.2} mm",
        a.mean_position_m * 1e3
    );
    for (axis, e) in ["roll", "pitch", "yaw"].iter().zip(a.mean_euler_deg) {
        assert!(e <= 1.0, "mean {axis} error {e:.3}°");
    }
}

/// The paper's Table 2 on the fast desktop sequence, and, with the IMU withheld, the
/// vision-only model (issue 14): the acc model predicts at least twice as well as every other,
/// vision-only included (measured: acc 0.17 px, vision-only 0.93 px).
#[test]
fn desktop_fast_the_acc_model_predicts_twice_as_well_and_meets_the_papers_accuracy() {
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let runs: Vec<(ModelKind, TrackRun)> = ModelKind::ALL
        .iter()
        .map(|&m| {
            let name = format!("desktop-fast-{m:?}");
            (m, track(&options(&ds, &name, m)))
        })
        .collect();
    let px = |m: ModelKind| mean_px(&runs.iter().find(|(k, _)| *k == m).unwrap().1);
    println!(
        "desktop-fast mean prediction error: gyro {:.3} px, gravity {:.3} px, acc {:.3} px, vision-only {:.3} px",
        px(ModelKind::Gyro),
        px(ModelKind::Gravity),
        px(ModelKind::Acc),
        px(ModelKind::Vision)
    );
    assert!(px(ModelKind::Acc) <= 0.5 * px(ModelKind::Gyro));
    assert!(px(ModelKind::Acc) <= 0.5 * px(ModelKind::Gravity));
    assert!(px(ModelKind::Acc) <= 0.5 * px(ModelKind::Vision));
    let (_, vision) = runs.iter().find(|(k, _)| *k == ModelKind::Vision).unwrap();
    assert!(!vision.summary.imu_used);
    let t = vision
        .summary
        .tracked
        .as_ref()
        .expect("vision-only frames are judged");
    assert!(t.share > 0.9, "{t:?}");
    let (_, acc) = runs.iter().find(|(k, _)| *k == ModelKind::Acc).unwrap();
    assert!(acc.summary.divergences.is_empty());
    assert_desktop_fast_accuracy(acc);
}

#[test]
fn desktop_fast_with_20_percent_outliers_still_meets_the_bounds() {
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let mut o = options(&ds, "desktop-fast-outliers", ModelKind::Acc);
    o.faults = Faults {
        outlier_fraction: 0.2,
        seed: 7,
        ..Faults::default()
    };
    let run = track(&o);
    let s = &run.summary;
    let share = s.injected_outliers as f64 / s.correspondences_sent as f64;
    println!(
        "outliers injected {} of {} ({:.1} %), gated {}",
        s.injected_outliers,
        s.correspondences_sent,
        100.0 * share,
        s.gated
    );
    assert!((0.17..0.23).contains(&share), "{share}");
    // Nearly every outlier is gated (a few land close to their true point by chance).
    assert!(s.gated as f64 >= 0.9 * s.injected_outliers as f64);
    assert!(s.divergences.is_empty(), "{:?}", s.divergences);
    assert_desktop_fast_accuracy(&run);
}

/// 0.3 s of nothing but outliers, in the middle of the fast figure eight. The core detects the
/// divergence and re-initialises softly (the estimate kept, the covariance restarted); until a
/// part of a frame agrees with it as a whole, the few outliers its wide gate lets through are
/// withheld (docs/FILTER.md §7), so tracking resumes as soon as the frames' correspondences are
/// good again. Two corruption seeds: before that rule, over seeds 1-6, every frame after 6.5 s had
/// vision on one seed at 8d9eafb and on none at cf922a8.
#[test]
fn a_forced_divergence_is_detected_and_tracking_resumes_by_itself() {
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    for seed in [3, 2] {
        let mut o = options(
            &ds,
            &format!("desktop-fast-divergence-{seed}"),
            ModelKind::Acc,
        );
        o.faults = Faults {
            corrupt_from: Some(6.0),
            corrupt_seconds: 0.3,
            seed,
            ..Faults::default()
        };
        let run = track(&o);
        let first = run
            .summary
            .divergences
            .first()
            .expect("divergence detected");
        assert!(
            (6.0..6.35).contains(&first.t),
            "seed {seed}: detected at {:.2} s",
            first.t
        );
        // Tracking resumes: every frame from 6.5 s on has accepted correspondences, and the
        // camera position of the predictions is as good as before.
        let after: Vec<_> = run.frames.iter().filter(|f| f.t >= 6.5).collect();
        assert!(after.len() > 100);
        let with_vision = after.iter().filter(|f| f.accepted > 0).count();
        assert_eq!(
            with_vision,
            after.len(),
            "seed {seed}: frames without vision after recovery"
        );
        let err = after.iter().filter_map(|f| f.position_error_m).sum::<f64>() / after.len() as f64;
        println!(
            "seed {seed}: divergence at {:.2} s ({}), {} divergences in all; mean predicted position error after 6.5 s {:.2} mm",
            first.t,
            first.reason,
            run.summary.divergences.len(),
            err * 1e3
        );
        assert!(err < 0.01, "seed {seed}: {err}");
    }
}

/// The paper's Fig. 6: with two features per frame the gyro model's attitude drifts while the
/// accelerometer keeps the gravity and acc models' tilt. On this seed the gyro model's tilt
/// error grows from 0.67° to 2.19°, gravity's stays at 0.3-0.6° and acc's at 0.15-0.28°. Seeds
/// 1 and 2 give gyro 0.68° / 1.95°, gravity 0.45° / 0.62°, acc below 0.4° at 27-30 s (closing
/// note of issue 8).
#[test]
fn desktop_slow_with_two_features_the_gyro_model_drifts_and_the_accelerometer_keeps_the_tilt() {
    let ds = dataset(ScenarioName::DesktopSlow, 30.0);
    let data = Dataset::open(&ds).unwrap();
    let mut late_tilt = std::collections::BTreeMap::new();
    for m in ModelKind::INERTIAL {
        let mut o = options(&ds, &format!("desktop-slow-2features-{m:?}"), m);
        o.vision.map.subset_size = 2;
        let run = track(&o);
        let e = tilt_errors(&data, &run);
        let (early, late) = (mean_between(&e, 2.0, 7.0), mean_between(&e, 25.0, 30.0));
        let worst = e.iter().map(|&(_, v)| v).fold(0.0, f64::max);
        println!("{m:?}: tilt error 2-7 s {early:.2}°, 25-30 s {late:.2}°, worst {worst:.2}°");
        assert!(run.summary.divergences.is_empty(), "{m:?}");
        match m {
            ModelKind::Acc => assert!(late < 0.5 && early < 0.5, "{early} {late}"),
            ModelKind::Gravity => assert!(late < 1.0 && early < 1.0, "{early} {late}"),
            // Drifts: the error grows, and ends above a degree.
            ModelKind::Gyro => assert!(late > 1.0 && late > 2.0 * early, "{early} {late}"),
            ModelKind::Vision => unreachable!("an inertial model"),
        }
        late_tilt.insert(format!("{m:?}"), late);
    }
    assert!(
        late_tilt["Gyro"] > 2.0 * late_tilt["Gravity"],
        "{late_tilt:?}"
    );
    assert!(late_tilt["Gyro"] > 4.0 * late_tilt["Acc"], "{late_tilt:?}");
}

#[test]
fn room_is_tracked_through_both_turns_the_shake_and_the_occlusion() {
    let ds = dataset(ScenarioName::Room, 45.0);
    let run = track(&options(&ds, "room-acc", ModelKind::Acc));
    assert!(
        run.summary.divergences.is_empty(),
        "{:?}",
        run.summary.divergences
    );
    // Frames with vision: all but the short stretches facing the unmodelled wall.
    let after: Vec<_> = run.frames.iter().filter(|f| f.t >= 1.0).collect();
    let share = after.iter().filter(|f| f.accepted > 0).count() as f64 / after.len() as f64;
    let a = run.summary.accuracy.unwrap();
    println!(
        "room: vision in {:.1} % of frames, mean position error {:.1} mm",
        100.0 * share,
        a.mean_position_m * 1e3
    );
    assert!(share > 0.9, "{share}");
    assert!(a.mean_position_m < 0.02);
    let _ = std::fs::remove_dir_all(search_cache("room"));
    assert_cold_start_tracks_as_the_given_start(&ds, "room", &run);
}

/// Issue 15: the same dataset tracked from a cold start (`--cold-start`): the first pose is
/// accepted within 0.5 s, and the accuracy and prediction error are those of the run from the
/// given start `given` (within 10 %, or 0.5 mm and 0.02 px).
fn assert_cold_start_tracks_as_the_given_start(
    ds: &std::path::Path,
    name: &str,
    given: &TrackRun,
) -> TrackRun {
    let mut o = options(ds, &format!("{name}-cold"), ModelKind::Acc);
    o.start.cold = true;
    o.cache = search_cache(name);
    let cold = track(&o);
    let c = cold.summary.cold_start.expect("a cold start was made");
    let (frame, t) = c.found.expect("the model was found");
    let (a, b) = (
        given.summary.accuracy.expect("ground truth"),
        cold.summary.accuracy.expect("ground truth"),
    );
    println!(
        "{name} cold start: found in frame {frame} at {t:.2} s after {} attempts ({:.0} ms each); \
         given start {:.2} mm, {:.3} px; cold start {:.2} mm, {:.3} px",
        c.attempts,
        c.mean_ms,
        a.mean_position_m * 1e3,
        mean_px(given),
        b.mean_position_m * 1e3,
        mean_px(&cold)
    );
    assert!(t <= 0.5, "first accepted pose at {t} s");
    assert!(
        cold.summary.divergences.is_empty(),
        "{:?}",
        cold.summary.divergences
    );
    assert!(b.mean_position_m <= a.mean_position_m * 1.1 + 0.0005);
    assert!(mean_px(&cold) <= mean_px(given) * 1.1 + 0.02);
    cold
}

/// The searches' database folder of the tests on scenario `name`.
fn search_cache(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("locate-cache")
        .join(name)
}

#[test]
fn foyer_the_acc_model_tracks_throughout_and_the_others_lose_track() {
    let ds = dataset(ScenarioName::Foyer, 30.0);
    for m in ModelKind::INERTIAL {
        let run = track(&options(&ds, &format!("foyer-{m:?}"), m));
        let diverged: Vec<String> = run
            .summary
            .divergences
            .iter()
            .map(|e| format!("{:.2} s ({})", e.t, e.reason))
            .collect();
        // Where the host saw the prediction lose the model (a drift the KLT's pyramid recovers
        // from never shows as a divergence).
        let lost: Vec<String> = run
            .summary
            .track_losses
            .iter()
            .map(|l| format!("{:.2}-{:.2} s", l.start, l.end))
            .collect();
        println!("foyer {m:?}: lost track at {lost:?}; divergences at {diverged:?}");
        if m == ModelKind::Acc {
            assert!(
                lost.is_empty() && diverged.is_empty(),
                "{lost:?} {diverged:?}"
            );
            let px = mean_px(&run);
            assert!(px <= 1.42, "mean prediction error {px:.3} px");
            let _ = std::fs::remove_dir_all(search_cache("foyer"));
            assert_cold_start_tracks_as_the_given_start(&ds, "foyer", &run);
        } else {
            assert!(
                !lost.is_empty(),
                "the {m:?} model was expected to lose track"
            );
        }
    }
}

#[test]
fn real_time_pacing_tracks_too() {
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let mut o = options(&ds, "desktop-fast-real-time", ModelKind::Acc);
    o.pacing = Pacing::RealTime;
    o.duration = Some(4.0);
    let run = track(&o);
    assert!(run.summary.frames >= 80, "{}", run.summary.frames);
    let a = run.summary.accuracy.unwrap();
    assert!(a.mean_position_m < 0.01, "{}", a.mean_position_m);
}

#[test]
fn bad_inputs_are_named() {
    let missing = options(
        &PathBuf::from("/nonexistent/dataset"),
        "missing",
        ModelKind::Acc,
    );
    let err = track::run(
        &missing,
        Arc::new(AtomicBool::new(false)),
        &mut |_, _, _, _| {},
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("/nonexistent/dataset: missing (dataset folder)"),
        "{err}"
    );

    // A dataset whose images are gone: frames are reported unusable, the run goes on.
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let broken = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("tracking-broken");
    let _ = std::fs::remove_dir_all(&broken);
    copy_dir(&ds, &broken);
    let data = broken.join("mav0/cam0/data");
    let mut images: Vec<PathBuf> = std::fs::read_dir(&data)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    images.sort();
    // Frame 40 (1.6 s): well after snap-on, within the 3 s tracked.
    let victim = images[40].clone();
    std::fs::write(&victim, b"not a png").unwrap();
    let mut o = options(&broken, "broken", ModelKind::Acc);
    o.duration = Some(3.0);
    let run = track(&o);
    assert_eq!(
        run.summary.frame_errors.len(),
        1,
        "{:?}",
        run.summary.frame_errors
    );
    assert!(
        run.summary.frame_errors[0].contains(victim.file_name().unwrap().to_str().unwrap()),
        "{:?}",
        run.summary.frame_errors
    );
}

#[test]
fn an_interrupted_run_still_writes_what_was_tracked() {
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let o = options(&ds, "desktop-fast-interrupted", ModelKind::Acc);
    let _ = std::fs::remove_dir_all(&o.out);
    let flag = Arc::new(AtomicBool::new(false));
    let stop = flag.clone();
    // Ctrl-C after 3 s of data.
    let run = track::run(&o, flag, &mut |done, _, _, _| {
        if done >= 300 {
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    })
    .unwrap();
    assert!(run.summary.stopped_early);
    assert!(
        (2.9..3.6).contains(&run.summary.duration_s),
        "{}",
        run.summary.duration_s
    );
    for f in ["trajectory.tum", "frames.csv"] {
        let text = std::fs::read_to_string(o.out.join(f)).unwrap();
        assert!(text.lines().count() > 50, "{f}");
    }
    let summary = std::fs::read_to_string(o.out.join("summary.json")).unwrap();
    assert!(summary.contains("\"stopped_early\": true"), "{summary}");
}

fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), &target).unwrap();
        }
    }
}

/// The firmware image, if it and `qemu-system-arm` are there; `None` (the test skips, with a
/// message) if not, unless `REQUIRE_FIRMWARE` is set, which makes that a failure.
fn firmware_image() -> Option<PathBuf> {
    let workspace = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let image = firmware_sim::qemu::default_image(&workspace, "device");
    let required = std::env::var_os("REQUIRE_FIRMWARE").is_some();
    let qemu_present = std::process::Command::new("qemu-system-arm")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !(image.exists() && qemu_present) {
        assert!(
            !required,
            "REQUIRE_FIRMWARE: need qemu-system-arm and {}",
            image.display()
        );
        println!(
            "SKIPPED: qemu-system-arm or {} absent (set REQUIRE_FIRMWARE to make this a failure)",
            image.display()
        );
        return None;
    }
    Some(image)
}

/// The same tracking run with the core as the firmware image under QEMU and as the simulated
/// board: lock-step replay makes both sessions the same byte stream, so the states agree.
/// Skips without `qemu-system-arm` or the image (`cargo xtask firmware`) unless
/// `REQUIRE_FIRMWARE` is set.
#[test]
fn tracking_over_the_firmware_under_qemu_matches_the_simulated_board() {
    let Some(image) = firmware_image() else {
        return;
    };
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let mut runs = Vec::new();
    for (name, link) in [
        ("qemu", track::LinkSpec::Qemu(image.clone())),
        ("sim", track::LinkSpec::Sim(tracker::Precision::F32)),
    ] {
        let mut o = options(&ds, &format!("desktop-fast-{name}"), ModelKind::Acc);
        o.link = link;
        o.duration = Some(4.0);
        runs.push(track(&o));
    }
    let (q, s) = (&runs[0], &runs[1]);
    assert_eq!(q.log.states.len(), s.log.states.len());
    assert!(q.log.states.len() > 300);
    let worst = q
        .log
        .states
        .iter()
        .zip(&s.log.states)
        .map(|(a, b)| {
            assert_eq!(a.t_us, b.t_us);
            (0..3)
                .map(|i| (a.s_w[i] - b.s_w[i]).abs())
                .fold(0.0f32, f32::max)
        })
        .fold(0.0f32, f32::max);
    println!(
        "firmware under QEMU vs simulated board: {} states, worst position difference {worst:e} m; accepted {} vs {}",
        q.log.states.len(),
        q.summary.accepted,
        s.summary.accepted
    );
    assert!(worst < 1e-4, "{worst}");
    assert_eq!(q.summary.accepted, s.summary.accepted);
}

/// The first time from which every frame until `t_end` has accepted correspondences and a
/// predicted camera position within 1 cm of the truth [s].
fn settled_from(run: &TrackRun, t0: f64, t_end: f64) -> Option<f64> {
    let rows: Vec<_> = run
        .frames
        .iter()
        .filter(|f| f.t >= t0 && f.t < t_end)
        .collect();
    let good = |f: &&host_vision::track::FrameRow| {
        f.accepted > 0 && f.position_error_m.is_some_and(|e| e < 0.01)
    };
    let last_bad = rows.iter().rposition(|f| !good(f));
    match last_bad {
        None => rows.first().map(|f| f.t),
        Some(i) => rows.get(i + 1).map(|f| f.t),
    }
}

/// Issue 15 on the synthetic scenarios: with no start pose (`--cold-start`: the ground truth
/// only evaluates), the model is found in the frames, the core is initialised from it with
/// roll and pitch from gravity, and tracking is as accurate as from the given start. A forced
/// loss (2 s of frames replaced by noise while the camera moves) is searched and recovered
/// within half a second of the frames being back.
#[test]
fn desktop_fast_from_a_cold_start_and_after_a_forced_loss() {
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let cache = search_cache("desktop-fast");
    let _ = std::fs::remove_dir_all(&cache);
    let given = track(&options(&ds, "desktop-fast-given", ModelKind::Acc));
    // The first search builds the database, and says so; later runs read it from the cache.
    let cold = assert_cold_start_tracks_as_the_given_start(&ds, "desktop-fast", &given);
    let built = cold.summary.search_database.clone().unwrap_or_default();
    assert!(built.starts_with("built: "), "{built}");

    // Over 2 s blind the acc model's dead reckoning keeps the model within the registration's
    // reach (tracking comes back by itself); over 4 s it does not, and the search finds it.
    for (blind_s, name) in [
        (2.0, "desktop-fast-cold-blind-2s"),
        (4.0, "desktop-fast-cold-blind-4s"),
    ] {
        let mut o = options(&ds, name, ModelKind::Acc);
        o.start.cold = true;
        o.cache = cache.clone();
        o.faults = Faults {
            blind_from: Some(5.0),
            blind_seconds: blind_s,
            seed: 3,
            ..Faults::default()
        };
        let end = 5.0 + blind_s;
        let lost = track(&o);
        let cached = lost.summary.search_database.clone().unwrap_or_default();
        assert!(cached.ends_with("(from the cache)"), "{cached}");
        for r in &lost.summary.recoveries {
            println!(
                "blind {blind_s} s: lost at {:.2} s, {} at {:?} s after {} attempts ({:.0} ms each)",
                r.lost_at,
                if r.found { "found" } else { "back by itself" },
                r.ended_at,
                r.attempts,
                r.mean_ms
            );
        }
        let back = settled_from(&lost, end, 12.0).expect("tracking settles after the loss");
        println!("blind {blind_s} s (to {end} s): tracking within 1 cm from {back:.2} s");
        assert!(
            back <= end + 0.5,
            "blind {blind_s} s: recovered only at {back} s"
        );
        let loss = lost
            .summary
            .recoveries
            .iter()
            .find(|r| (5.0..end).contains(&r.lost_at))
            .expect("the loss is recorded");
        assert!(loss.ended_at.is_some_and(|t| t <= end + 0.5), "{loss:?}");
        if blind_s > 3.0 {
            assert!(loss.found, "the loss was not ended by a search: {loss:?}");
        }
    }
}

/// Issue 17, a noisy line: bit errors at 10⁻⁴ and 10⁻³ per byte, in both directions, on the
/// line to the simulated board. Every damaged frame is detected and dropped at both ends (a
/// flipped delimiter can merge two damaged frames into one, or split one in two), nothing
/// damaged is applied (the core found no invalid message), and tracking degrades gracefully.
#[test]
fn a_noisy_line_is_detected_at_both_ends_and_tracking_degrades_gracefully() {
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let mut rows = Vec::new();
    for rate in [0.0, 1e-4, 1e-3] {
        let mut o = options(&ds, &format!("desktop-fast-line-{rate:e}"), ModelKind::Acc);
        o.faults.line_errors = Some(rate);
        let run = track(&o);
        let line = run.summary.line.expect("the line's figures");
        assert_eq!(line.invalid_at_core, Some(0), "{rate}: {line:?}");
        let refused_by_core = line.refused_by_core.expect("the board's report");
        for (damaged, refused) in [
            (line.damaged_to_core, refused_by_core),
            (line.damaged_to_host, line.refused_by_host),
        ] {
            assert!(
                refused as f64 >= 0.9 * damaged as f64
                    && refused as f64 <= 1.1 * damaged as f64 + 2.0,
                "{rate}: {damaged} damaged, {refused} refused"
            );
        }
        if rate > 0.0 {
            assert!(
                line.damaged_to_core > 0 && line.damaged_to_host > 0,
                "{line:?}"
            );
        }
        assert!(
            run.summary.divergences.is_empty(),
            "{rate}: {:?}",
            run.summary.divergences
        );
        let a = run.summary.accuracy.expect("ground truth");
        rows.push((rate, mean_px(&run), a.mean_position_m, line));
    }
    println!(
        "byte error rate | prediction error [px] | position error [mm] | damaged to core / refused | damaged to host / refused"
    );
    for (rate, px, pos, l) in &rows {
        println!(
            "{rate:e} | {px:.3} | {:.2} | {} / {:?} | {} / {}",
            pos * 1e3,
            l.damaged_to_core,
            l.refused_by_core,
            l.damaged_to_host,
            l.refused_by_host
        );
    }
    let (clean_px, clean_pos) = (rows[0].1, rows[0].2);
    for (rate, px, pos, _) in &rows[1..] {
        assert!(*px <= 4.0 * clean_px, "{rate}: {px} px against {clean_px}");
        assert!(
            *pos <= 3.0 * clean_pos + 0.001,
            "{rate}: {pos} m against {clean_pos}"
        );
    }
}

/// Position error [m] of the IMU estimate of every state from `from` [s] on, against the
/// ground truth.
fn position_errors_from(dataset: &Dataset, run: &TrackRun, from: f64) -> Vec<f64> {
    let stamp0 = dataset.imu[0].stamp;
    run.log
        .states
        .iter()
        .filter(|s| s.t_us as f64 * 1e-6 >= from)
        .filter_map(|s| {
            let (p_true, _) = dataset.groundtruth_at(stamp0 + s.t_us * 1000)?;
            let (p_est, _) = track::state_pose(s);
            Some((p_true - p_est).norm())
        })
        .collect()
}

/// The stamps [s] of a TUM file's poses.
fn tum_stamps(path: &std::path::Path) -> Vec<f64> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| l.split_whitespace().next().unwrap().parse::<f64>().unwrap())
        .collect()
}

/// The one outage of a run whose core was reset once, checked: noticed within 0.1 s, and
/// tracking again within 1 s of the reset. Returns it, with the reset's and that time [s].
fn reset_recovered(run: &TrackRun) -> (&track::Outage, f64, f64) {
    let outages = &run.summary.outages;
    assert_eq!(outages.len(), 1, "{outages:#?}");
    let out = &outages[0];
    assert_eq!(out.kind, track::OutageKind::CoreReset, "{out:#?}");
    let at = out.injected_s.expect("an injected fault");
    let back = out.tracking_s.expect("tracking again");
    println!(
        "reset at {at:.3} s: noticed at {:.3} s ({:.2} ms wall), {} attempts, back at {:?}, tracking at {back:.3} s",
        out.noticed_s,
        out.notice_wall_ms.unwrap_or(f64::NAN),
        out.attempts,
        out.resumed_s
    );
    assert!(out.noticed_s - at <= 0.1, "{out:#?}");
    assert!(back - at <= 1.0, "{out:#?}");
    (out, at, back)
}

/// Issue 17, the MCU resets while tracking (the simulated board's reset line, at 6 s of the
/// fast figure eight): the host notices within 0.1 s (the reset core refuses the next sample
/// as unannounced), shakes hands again, finds no session in the `HelloAck`, configures the
/// core and starts it again from the last state it reported while tracking (`Resume`), and
/// tracking resumes within 1 s. No pose in `trajectory.tum` comes from a core that did not
/// have one: the file has a hole from the reset until the new core was started again.
#[test]
fn a_core_reset_while_tracking_is_noticed_and_tracking_resumes_within_a_second() {
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let mut o = options(&ds, "desktop-fast-core-reset", ModelKind::Acc);
    o.faults.reset_core_at = Some(6.0);
    let run = track(&o);
    let s = &run.summary;
    let (out, at, back) = reset_recovered(&run);
    // The gap: nothing from the reset until the host reached the new core and started it
    // again from the last state it had tracked.
    let restarted = out.resumed_s.expect("reached again");
    let in_gap = |t: f64| t > at + 1e-6 && t < restarted - 1e-6;
    assert!(
        !run.log
            .states
            .iter()
            .any(|st| in_gap(st.t_us as f64 * 1e-6)),
        "a state between the reset at {at} s and the restart at {restarted} s"
    );
    let stamp0 = s.t0_stamp_ns as f64 * 1e-9;
    let stamps = tum_stamps(&o.out.join("trajectory.tum"));
    assert!(!stamps.iter().any(|&t| in_gap(t - stamp0)));
    assert!(stamps.iter().any(|&t| t - stamp0 > restarted));
    let tum = std::fs::read_to_string(o.out.join("trajectory.tum")).unwrap();
    assert!(
        tum.contains("# gap: CoreReset from 6.000 s"),
        "the gap is not marked"
    );
    // And tracking is as good as before once it is back.
    let errors = position_errors_from(&Dataset::open(&ds).unwrap(), &run, back + 1.0);
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    println!(
        "position error from {:.2} s: mean {:.2} mm",
        back + 1.0,
        mean * 1e3
    );
    assert!(errors.len() > 100 && mean < 0.01, "{mean} m");
}

/// Issue 17, the cable is pulled for 0.5 s while tracking (the host's pty is closed, and
/// opening a new one fails until the cable is back): the host retries with back-off, the core
/// keeps its state, and on the host's return it is sent the samples it missed: it
/// dead-reckons through the gap, reports so, and tracking resumes. The replay in lock-step is
/// deterministic: two runs with the same cut agree state for state, and agree with a run
/// without a cut up to it.
#[test]
fn a_pulled_cable_is_bridged_by_dead_reckoning_and_the_replay_stays_deterministic() {
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let run = |name: &str, cut: bool| {
        let mut o = options(&ds, name, ModelKind::Acc);
        if cut {
            o.faults.cut_link_at = Some(6.0);
            o.faults.cut_seconds = 0.5;
        }
        track(&o)
    };
    let clean = run("desktop-fast-clean", false);
    let a = run("desktop-fast-cut-a", true);
    let b = run("desktop-fast-cut-b", true);
    assert_eq!(a.summary.outages.len(), 1, "{:#?}", a.summary.outages);
    let out = &a.summary.outages[0];
    assert_eq!(out.kind, track::OutageKind::LinkLost, "{out:#?}");
    let at = out.injected_s.expect("an injected fault");
    let resumed = out.resumed_s.expect("reconnected");
    let back = out.tracking_s.expect("tracking again");
    println!(
        "cable out at {at:.3} s for 0.5 s: {} attempts, reconnected at {resumed:.3} s, {} samples caught up, tracking at {back:.3} s",
        out.attempts, out.backlog
    );
    // Back-off from 10 ms doubling: the attempts at 10, 30, 70, 150, 310 and 630 ms.
    assert!(out.attempts >= 3, "{out:#?}");
    assert!((0.5..=0.7).contains(&(resumed - at)), "{out:#?}");
    let rate = Dataset::open(&ds).unwrap().imu_rate_hz;
    let gap_samples = (resumed - at) * rate;
    assert!(
        (out.backlog as f64 - gap_samples).abs() <= 2.0,
        "{} samples caught up for a gap of {gap_samples}",
        out.backlog
    );
    // The core dead-reckoned through the gap, and said so once the host was back.
    assert!(
        a.log.statuses.iter().any(|st| {
            let t = st.t_us as f64 * 1e-6;
            st.mode == protocol::Mode::DeadReckoning && t > at && t < resumed
        }),
        "{:?}",
        a.log.statuses
    );
    assert!(back - resumed <= 1.0, "{out:#?}");
    // Deterministic apart from the gap.
    assert_eq!(a.log.states.len(), b.log.states.len());
    assert!(
        a.log.states == b.log.states,
        "two runs with the same cut differ"
    );
    let before = |r: &TrackRun| -> Vec<protocol::StateReport> {
        r.log
            .states
            .iter()
            .filter(|s| (s.t_us as f64) * 1e-6 < at)
            .copied()
            .collect()
    };
    let (clean_before, cut_before) = (before(&clean), before(&a));
    assert!(clean_before.len() > 300);
    let first_difference = clean_before
        .iter()
        .zip(&cut_before)
        .position(|(x, y)| x != y);
    assert!(
        clean_before.len() == cut_before.len() && first_difference.is_none(),
        "the run with the cut differs before it: {} and {} states, first difference at {:?}: {:?}",
        clean_before.len(),
        cut_before.len(),
        first_difference,
        first_difference.map(|i| (clean_before[i], cut_before[i]))
    );
    let ds_open = Dataset::open(&ds).unwrap();
    let mean = |r: &TrackRun| {
        let e = position_errors_from(&ds_open, r, back + 1.0);
        e.iter().sum::<f64>() / e.len() as f64
    };
    let (m_clean, m_cut) = (mean(&clean), mean(&a));
    println!(
        "position error from {:.2} s: {:.2} mm with the cut, {:.2} mm without",
        back + 1.0,
        m_cut * 1e3,
        m_clean * 1e3
    );
    assert!(m_cut < 0.01, "{m_cut}");
}

/// Issue 17, the host restarts while the core keeps running, over TCP: host A tracks the
/// first 6 s and goes; host B attaches (`--attach`), asks the core for its state, and goes on
/// from the core's last sample without configuring or initialising it. On the way B's TCP
/// connection is lost once and made again.
#[test]
fn a_restarted_host_attaches_to_the_running_core_over_tcp() {
    use firmware_sim::board::{Board, Precision, ResetPin};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    // The board serves host after host with one core, as firmware-sim --forever does.
    std::thread::spawn(move || {
        let mut board = Board::new(Precision::F32, ResetPin::default());
        while let Ok(link) = firmware_sim::transport::tcp_accept(&listener) {
            let _ = board.serve(link);
        }
    });
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let mut o = options(&ds, "desktop-fast-host-a", ModelKind::Acc);
    o.link = track::LinkSpec::Tcp(addr.clone());
    o.duration = Some(6.0);
    let first = track(&o);
    let last_a = first.log.states.last().expect("host A tracked").t_us;
    let mut o = options(&ds, "desktop-fast-host-b", ModelKind::Acc);
    o.link = track::LinkSpec::Tcp(addr);
    o.attach = true;
    o.faults.cut_link_at = Some(9.0);
    o.faults.cut_seconds = 0.1;
    let second = track(&o);
    let note = second.summary.attach.clone().unwrap_or_default();
    assert!(note.starts_with("attached to session"), "{note}");
    // Nothing was configured or initialised again.
    assert!(
        !second.log.statuses.iter().any(|s| matches!(
            s.reason,
            protocol::StatusReason::Configured | protocol::StatusReason::HostRequest
        )),
        "{:?}",
        second.log.statuses
    );
    let first_b = second.log.states.first().expect("host B tracked").t_us;
    let period_us = 1e6 / Dataset::open(&ds).unwrap().imu_rate_hz;
    assert!(
        (first_b - last_a) as f64 <= 1.5 * period_us,
        "B began at {first_b} µs, A ended at {last_a} µs"
    );
    assert_eq!(second.summary.outages.len(), 1);
    assert_eq!(
        second.summary.outages[0].kind,
        track::OutageKind::LinkLost,
        "{:#?}",
        second.summary.outages
    );
    let errors = position_errors_from(&Dataset::open(&ds).unwrap(), &second, 6.0);
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    println!(
        "host B from {:.3} s: mean position error {:.2} mm",
        first_b as f64 * 1e-6,
        mean * 1e3
    );
    assert!(errors.len() > 300 && mean < 0.01, "{mean}");
}

/// Issue 17, the MCU resets while tracking, on the firmware under QEMU: QEMU is killed at 2 s
/// and, when the host reconnects, booted again. The host notices the line's end, reaches the
/// new core (its `HelloAck` has no session), configures it, resumes it from the last tracked
/// state, and tracking is back within 1 s of the input's time.
#[test]
fn a_firmware_reset_under_qemu_is_noticed_and_tracking_resumes() {
    let Some(image) = firmware_image() else {
        return;
    };
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    let mut o = options(&ds, "desktop-fast-qemu-reset", ModelKind::Acc);
    o.link = track::LinkSpec::Qemu(image);
    o.duration = Some(4.0);
    o.faults.reset_core_at = Some(2.0);
    let run = track(&o);
    let (_, _, back) = reset_recovered(&run);
    let errors = position_errors_from(&Dataset::open(&ds).unwrap(), &run, back + 0.5);
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    println!(
        "position error from {:.2} s: mean {:.2} mm",
        back + 0.5,
        mean * 1e3
    );
    assert!(errors.len() > 50 && mean < 0.01, "{mean} m");
}

/// Issue 17, a serial device that disappears and comes back under another name: the board is
/// a pty whose device is published as `tty-0` in a folder, and the host's link is
/// `serial:FOLDER/tty-*`. When the host's end closes (the cable pulled for 0.3 s), the board
/// makes a new pty, published as `tty-1`; the host's reconnection finds it by the pattern, the
/// core has kept its state, and tracking goes on.
#[test]
fn a_serial_device_that_comes_back_under_another_name_is_found_again() {
    use firmware_sim::board::{Board, Precision, ResetPin};
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("serial-devices");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let published = dir.clone();
    std::thread::spawn(move || {
        let mut board = Board::new(Precision::F32, ResetPin::default());
        for n in 0.. {
            let Ok((link, device)) = firmware_sim::transport::pty_for_peer() else {
                return;
            };
            let name = published.join(format!("tty-{n}"));
            std::os::unix::fs::symlink(&device, &name).unwrap();
            let _ = board.serve(link);
            let _ = std::fs::remove_file(&name);
        }
    });
    let ds = dataset(ScenarioName::DesktopFast, 12.0);
    // The board publishes its first device from its own thread: the host starts once it is
    // there (with the dataset cached, it could start first and find none).
    let first = dir.join("tty-0");
    let waited = std::time::Instant::now();
    while std::fs::symlink_metadata(&first).is_err() {
        assert!(
            waited.elapsed() < std::time::Duration::from_secs(30),
            "the board published no device"
        );
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let mut o = options(&ds, "desktop-fast-serial-renamed", ModelKind::Acc);
    o.link = track::LinkSpec::Serial {
        path: format!("{}/tty-*", dir.display()),
        baud: core_link::DEFAULT_BAUD,
    };
    o.duration = Some(8.0);
    o.faults.cut_link_at = Some(5.0);
    o.faults.cut_seconds = 0.3;
    let run = track(&o);
    let s = &run.summary;
    assert_eq!(s.outages.len(), 1, "{:#?}", s.outages);
    let out = &s.outages[0];
    assert_eq!(out.kind, track::OutageKind::LinkLost, "{out:#?}");
    let back = out.tracking_s.expect("tracking again");
    println!(
        "device renamed: {} attempts (the last failure: {:?}), back at {:?}, tracking at {back:.3} s",
        out.attempts, out.last_failure, out.resumed_s
    );
    assert!(back <= 6.5, "{out:#?}");
    // The device it came back to is the new one.
    let on = out.resumed_on.clone().unwrap_or_default();
    assert!(on.ends_with("tty-1"), "back on {on}");
    let errors = position_errors_from(&Dataset::open(&ds).unwrap(), &run, back + 0.5);
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    assert!(errors.len() > 100 && mean < 0.01, "{mean} m");
}
