//! Issue 14 on real footage: the shared cube video (`../shared/data/visp-cube`: 989 frames of
//! 640×480 at 30 fps, a picture cube on a desk pushed, turned, hidden behind a mug and lifted
//! by a hand; no IMU, no ground truth) tracked vision-only from its frame-0 pose. Skipped, saying
//! so, when the data is not there.
//!
//! What the frames show (judged from the run's overlays, `--overlay-every 10`): the cube stands
//! still until frame 92, is pushed (92-150), turned (210-250, 320-410), and from frame 548 the
//! hand brings the mug in front of it and moves both to the right; until about frame 750 the
//! mug covers half of the cube or more, and the tracker follows the part still visible. After the
//! mug the cube is lifted and turned in the air. The frames judged at least half visible are
//! all but 548-749.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use host_vision::start_pose::read_start_pose;
use host_vision::track::{self, FrameRow};

mod cube;

fn data() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/visp-cube");
    if dir.join("cube_video.mp4").exists() {
        Some(dir)
    } else {
        println!(
            "skipped: {} is not there (the shared data of issue 14)",
            dir.display()
        );
        None
    }
}

fn share(rows: &[&FrameRow]) -> f64 {
    let judged: Vec<bool> = rows.iter().filter_map(|r| r.tracked).collect();
    judged.iter().filter(|&&t| t).count() as f64 / judged.len().max(1) as f64
}

/// The README as one line of words (its figures wrap across lines).
fn readme() -> String {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"))
        .unwrap();
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Issue 54, point 25: the README's figures of the cube video come from these runs (`cargo test
/// -p host-vision --test visp_cube -- --nocapture` prints them), under the renderer the README
/// names (Mesa's lavapipe on Vulkan); elsewhere they are printed, not compared. Each of
/// `figures` must be in the README as it is written.
fn readme_says(adapter: &str, figures: &[String]) {
    if !(adapter.contains("llvmpipe") && adapter.contains("Vulkan")) {
        println!("README figures not compared under {adapter}: {figures:?}");
        return;
    }
    let readme = readme();
    let stale: Vec<&String> = figures
        .iter()
        .filter(|f| !readme.contains(f.as_str()))
        .collect();
    assert!(
        stale.is_empty(),
        "the README does not say what this run gives, {stale:?}: write these figures in it"
    );
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
fn the_cube_video_is_tracked_vision_only_through_pushes_turns_and_the_mug() {
    let Some(dir) = data() else { return };
    let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("visp-cube");
    let mut o = cube::vision_only(&dir, out.clone());
    o.start.pose = Some(read_start_pose(&dir.join("frame0_pose.json")).unwrap());
    o.overwrite = true;
    let run = track::run(&o, Arc::new(AtomicBool::new(false)), &mut |_, _, _, _| {})
        .expect("the cube video tracks");
    let s = &run.summary;
    println!("{s}");
    assert_eq!(s.model, "vision");
    assert!(!s.imu_used);
    assert!(s.frames > 900, "{} frames analysed", s.frames);

    let rows: Vec<&FrameRow> = run.frames.iter().collect();
    let by_index = |lo: usize, hi: usize| -> Vec<&FrameRow> {
        rows.iter()
            .copied()
            .filter(|r| (lo..hi).contains(&r.index))
            .collect()
    };
    // The cube at rest, unoccluded: tracked, and the rendering at the estimate matches.
    let rest = by_index(0, 90);
    let ncc = median(rest.iter().filter_map(|r| r.ncc).collect());
    let rms = median(rest.iter().filter_map(|r| r.rms_px).collect());
    println!(
        "at rest: {:.1} % tracked, median ncc {ncc:.3}, median rms {rms:.2} px",
        100.0 * share(&rest)
    );
    assert!(share(&rest) >= 0.9, "{}", share(&rest));
    assert!(ncc > 0.55 && rms < 1.0, "{ncc} {rms}");
    // While the mug covers most of the cube, the rendering at the estimate correlates poorly
    // with the live image: those frames are not reported as tracked. The pose itself stays on
    // the visible part (the overlays show the outline on the cube), so tracking resumes after
    // the mug without a new start.
    let behind_mug = by_index(600, 700);
    assert!(!behind_mug.is_empty());
    println!(
        "behind the mug (600-699): {:.1} % tracked",
        100.0 * share(&behind_mug)
    );
    assert!(share(&behind_mug) <= 0.3, "{}", share(&behind_mug));
    let half_visible: Vec<&FrameRow> = rows
        .iter()
        .copied()
        .filter(|r| !(548..750).contains(&r.index))
        .collect();
    let lost_at = s
        .track_losses
        .iter()
        .find(|l| !l.recovered)
        .map(|l| l.start);
    println!(
        "{}: first unrecovered loss at {lost_at:?} s; tracked: {:.1} % of the frames judged at least half visible, {:.1} % before the mug (0-547), {:.1} % after it (750-), {:.1} % of the whole video",
        s.adapter,
        100.0 * share(&half_visible),
        100.0 * share(&by_index(0, 548)),
        100.0 * share(&by_index(750, usize::MAX)),
        100.0 * share(&rows)
    );
    // Measured (issue 33, `cargo test -p host-vision --test visp_cube -- --nocapture`): 98.5 % of
    // the half-visible frames under Mesa's Vulkan renderer (98.4 % before the mug, 98.7 % after
    // it) and 98.0 % under its GL renderer (97.6 %, 98.7 %; xtask's second pass): the frames
    // missing are the hardest moments of the pushes and turns. Under Vulkan the hand and the
    // mug lose the cube at 18.4 s, and a search finds it at 24.9 s, after the mug (548-749).
    let (tracked, judged) = (
        s.tracked.as_ref().unwrap().tracked,
        s.tracked.as_ref().unwrap().frames,
    );
    readme_says(
        &s.adapter,
        &[
            format!(
                "tracks {tracked} of the {judged} frames judged ({:.1} %)",
                100.0 * tracked as f64 / judged as f64
            ),
            format!(
                "texture alone: {tracked} of {judged}, {:.1} %",
                100.0 * share(&half_visible)
            ),
            format!("the Rust example tracks {tracked} of {judged}"),
        ],
    );
    assert_eq!(lost_at, None, "tracking lost for good");
    assert!(share(&half_visible) >= 0.96, "{}", share(&half_visible));
    assert!(share(&by_index(0, 548)) >= 0.95);
    assert!(share(&by_index(750, usize::MAX)) >= 0.96);
    still_stretch_holds(&out, &rows, s);
}

/// Issue 33: frames 796-840, where the cube stands nearly still with one face to the camera.
/// The tilt check once flipped the pose there every sixth frame, 94 mm and 11° each time, with
/// every frame reported tracked. Now: no flip there, and between consecutive tracked frames the
/// estimate (`trajectory_frames.tum`) moves less than 2 cm and 2°.
fn still_stretch_holds(out: &Path, rows: &[&FrameRow], s: &track::output::Summary) {
    const STILL: std::ops::RangeInclusive<usize> = 796..=840;
    let flips: Vec<usize> = s.tilt_checks.flips.iter().map(|f| f.frame).collect();
    assert!(
        !flips.iter().any(|f| STILL.contains(f)),
        "tilt flips while the cube stands still: {flips:?}"
    );
    let text = std::fs::read_to_string(out.join("trajectory_frames.tum")).unwrap();
    // Time [s] (as in frames.csv, to the µs) → position and quaternion (x, y, z, w).
    let poses: std::collections::BTreeMap<i64, [f64; 7]> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            (
                (v[0] * 1e6).round() as i64,
                core::array::from_fn(|i| v[i + 1]),
            )
        })
        .collect();
    let pose_of = |r: &FrameRow| poses.get(&((r.t * 1e6).round() as i64)).copied();
    let (mut pairs, mut worst_m, mut worst_deg) = (0, 0.0f64, 0.0f64);
    for w in rows.windows(2) {
        let (a, b) = (w[0], w[1]);
        if !(STILL.contains(&a.index) && b.index == a.index + 1) {
            continue;
        }
        if a.tracked != Some(true) || b.tracked != Some(true) {
            continue;
        }
        let (pa, pb) = (pose_of(a).unwrap(), pose_of(b).unwrap());
        let moved =
            ((pa[0] - pb[0]).powi(2) + (pa[1] - pb[1]).powi(2) + (pa[2] - pb[2]).powi(2)).sqrt();
        let dot = (3..7).map(|i| pa[i] * pb[i]).sum::<f64>().abs().min(1.0);
        let turned = 2.0 * dot.acos().to_degrees();
        worst_m = worst_m.max(moved);
        worst_deg = worst_deg.max(turned);
        pairs += 1;
        assert!(
            moved < 0.02 && turned < 2.0,
            "frames {}-{}: the estimate moved {:.1} mm and {turned:.2}° while the cube stood still",
            a.index,
            b.index,
            moved * 1e3
        );
    }
    println!(
        "still (796-840): {pairs} consecutive tracked pairs, the estimate moved at most {:.1} mm and {worst_deg:.2}°; tilt flips at {flips:?}",
        worst_m * 1e3
    );
    // Measured: 45 pairs, at most 3.2 mm and 0.39° (Vulkan), 3.4 mm and 0.36° (GL). Most of the
    // stretch must be tracked for the bound to say anything.
    assert!(
        pairs >= 30,
        "only {pairs} consecutive tracked pairs in 796-840"
    );
}

/// Issue 15: the same video with no start pose, and a forced loss: every correspondence
/// corrupted for 0.3 s from 10 s, while the cube is being turned. The cold start finds the cube
/// in the first frame it tries; after the loss the search finds it again; tracking goes on as
/// from the given pose.
#[test]
fn the_cube_video_is_tracked_from_a_cold_start_and_found_again_after_a_loss() {
    let Some(dir) = data() else { return };
    let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("visp-cube-cold");
    let mut o = cube::vision_only(&dir, out);
    o.overwrite = true;
    o.faults.corrupt_from = Some(10.0);
    o.faults.corrupt_seconds = 0.3;
    let run = track::run(&o, Arc::new(AtomicBool::new(false)), &mut |_, _, _, _| {})
        .expect("the cube video tracks from a cold start");
    let s = &run.summary;
    println!("{s}");
    let cold = s.cold_start.expect("a cold start was made");
    let (frame, _) = cold.found.expect("the cube was found");
    assert!(frame <= 5, "found only in frame {frame}");
    let half_visible: Vec<&FrameRow> = run
        .frames
        .iter()
        .filter(|r| !(548..750).contains(&r.index))
        .collect();
    println!(
        "cold start: found in frame {frame} after {} attempts ({:.0} ms each); {:.1} % of the half-visible frames tracked, {:.1} % of the whole video",
        cold.attempts,
        cold.mean_ms,
        100.0 * share(&half_visible),
        100.0 * share(&run.frames.iter().collect::<Vec<_>>())
    );
    // The forced loss: found again within a second of the corruption's end (10.3 s).
    for r in &s.recoveries {
        println!(
            "lost at {:.2} s, {} at {:?} s after {} attempts ({:.0} ms each)",
            r.lost_at,
            if r.found { "found" } else { "back by itself" },
            r.ended_at,
            r.attempts,
            r.mean_ms
        );
    }
    let forced = s
        .recoveries
        .iter()
        .find(|r| (9.9..10.6).contains(&r.lost_at))
        .expect("the forced loss is searched");
    assert!(forced.found, "{forced:?}");
    assert!(forced.ended_at.is_some_and(|t| t <= 11.3), "{forced:?}");
    readme_says(
        &s.adapter,
        &[format!(
            "the model is found again at {:.2} s, after {}. {:.1} % of the half-visible frames are tracked.",
            forced.ended_at.unwrap(),
            if forced.attempts == 1 {
                "1 attempt".to_string()
            } else {
                format!("{} attempts", forced.attempts)
            },
            100.0 * share(&half_visible)
        )],
    );
    // Measured 94.8 % (98.5 % from the given pose without the loss), Vulkan.
    assert!(share(&half_visible) >= 0.9, "{}", share(&half_visible));
}

/// Issue 37's modalities on the cube video from its frame-0 pose: the contour alone (its
/// texture ignored) and both together, as the README gives them (issue 54, point 25).
#[test]
fn the_cube_videos_contour_and_both_modalities_give_the_readmes_figures() {
    let Some(dir) = data() else { return };
    let mut figures = Vec::new();
    let mut adapter = String::new();
    for modality in [vision::Modality::Contour, vision::Modality::Both] {
        let out =
            PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("visp-cube-{modality:?}"));
        let mut o = cube::vision_only(&dir, out);
        o.start.pose = Some(read_start_pose(&dir.join("frame0_pose.json")).unwrap());
        o.modality = Some(modality);
        o.overwrite = true;
        let run = track::run(&o, Arc::new(AtomicBool::new(false)), &mut |_, _, _, _| {})
            .expect("the cube video tracks");
        let s = &run.summary;
        let half: Vec<&FrameRow> = run
            .frames
            .iter()
            .filter(|r| !(548..750).contains(&r.index))
            .collect();
        let judged = half.iter().filter(|r| r.tracked.is_some()).count();
        let tracked = half.iter().filter(|r| r.tracked == Some(true)).count();
        let all = s.tracked.as_ref().unwrap();
        println!(
            "{modality:?}: {} of {} frames tracked; {tracked} of the {judged} half-visible ({:.1} %)",
            all.tracked,
            all.frames,
            100.0 * share(&half)
        );
        figures.push(match modality {
            vision::Modality::Contour => format!(
                "tracks {:.1} % of the frames where the cube is at least half visible ({tracked} of {judged})",
                100.0 * share(&half)
            ),
            _ => format!(
                "Both modalities together track {} of its {} frames, {:.1} % of the half-visible ones",
                all.tracked,
                all.frames,
                100.0 * share(&half)
            ),
        });
        adapter = s.adapter.clone();
    }
    readme_says(&adapter, &figures);
}

/// Live, a search runs beside the frames (issue 35): with every attempt held to at least
/// 500 ms, the frames pushed meanwhile are each analysed at once and tracked, and the pose it
/// found is the pose of its own frame, given to the core at a later one.
#[test]
fn live_a_500_ms_search_never_holds_up_the_frames_and_its_pose_is_its_own_frames() {
    use std::time::{Duration, Instant};
    use tracker::{Answers, Event, InProcessCore, Start, Tracker, TrackerConfig};

    let Some(dir) = data() else { return };
    let o = cube::vision_only(
        &dir,
        PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("unused"),
    );
    let model = host_vision::model::load(o.model.as_ref().unwrap()).unwrap();
    // The database first, as a user's second run finds it: the search is the attempt alone.
    host_vision::locate::database::Database::load_or_build(
        &model,
        &Default::default(),
        &o.cache,
        &mut |_, _| {},
    )
    .unwrap();
    let mut config = TrackerConfig::new(o.camera.unwrap(), 30.0, o.cache.clone());
    config.start = Start::Camera(read_start_pose(&dir.join("frame0_pose.json")).unwrap());
    config.tuning = o.tuning;
    config.answers = Answers::WhenReady;
    config.search_floor = Duration::from_millis(500);
    config.details = true;
    let mut record = tracker::record::Record::default();
    let core = InProcessCore::default();
    let mut tracker = Tracker::new(config, &model, core).unwrap();

    let frames = o
        .frames
        .as_ref()
        .unwrap()
        .open(&Default::default())
        .unwrap()
        .take(150);
    let start = Instant::now();
    let mut reports = Vec::new();
    let mut located = None;
    let mut pushes_during_search = Vec::new();
    for frame in frames {
        let frame = frame.unwrap();
        let index = frame.index;
        // As a camera at 30 fps delivers them.
        let due = Duration::from_nanos(u64::try_from(frame.t_ns).unwrap());
        std::thread::sleep(due.saturating_sub(start.elapsed()));
        if index == 10 {
            tracker.relocate().unwrap();
        }
        let pushed = Instant::now();
        tracker.push_frame(frame.into()).unwrap();
        let took = pushed.elapsed();
        for e in tracker.poll() {
            record.observe(&e);
            match e {
                Event::Frame(r) => reports.push(r),
                Event::Located { index, pose } => located = Some((index, pose)),
                _ => {}
            }
        }
        if index >= 10 && located.is_none() {
            pushes_during_search.push((index, took));
        }
        if located.is_some_and(|(i, _)| index >= i + 30) {
            break;
        }
    }
    let done = tracker.finish();
    done.result.unwrap();
    record.observe_all(&done.events);
    let (found_at, pose) = located.expect("the search answered");
    let pose = pose.expect("the cube found");
    let search = &record.recoveries[0].searches[0];
    println!(
        "search on frame {found_at} ({:.0} ms on its thread), applied at {:?} s; {} frames pushed meanwhile, the longest push {:?}",
        search.ms,
        search.applied_at,
        pushes_during_search.len(),
        pushes_during_search.iter().map(|p| p.1).max()
    );
    // The search took a frame after the relocation (the first with the search thread free of
    // a tilt check), and its pose was given to the core at a later frame, at least the 500 ms
    // later.
    assert_eq!(found_at, search.index);
    assert!((10..40).contains(&found_at), "{found_at}");
    let applied = search.applied_at.expect("applied");
    assert!(applied >= search.t + 0.45, "{applied} vs {}", search.t);
    // The frames kept coming: each pushed during the search analysed at once, none of them
    // waiting for it.
    assert!(pushes_during_search.len() >= 10, "{pushes_during_search:?}");
    for &(index, took) in &pushes_during_search {
        assert!(took < Duration::from_millis(300), "frame {index}: {took:?}");
        let r = reports.iter().find(|r| r.index == index).unwrap();
        assert!(r.pose.is_some(), "frame {index} analysed");
    }
    // The pose found is its own frame's: where tracking had the cube on that frame (at rest).
    let tracked = reports
        .iter()
        .find(|r| r.index == found_at)
        .unwrap()
        .pose
        .unwrap();
    let metres = (pose.c_w - tracked.c_w).norm();
    let degrees = pose.q_cw.angle_to(&tracked.q_cw).to_degrees();
    assert!(metres < 0.01 && degrees < 2.0, "{metres} m, {degrees}°");
    // And tracking goes on from it.
    let after: Vec<_> = reports.iter().filter(|r| r.index > found_at + 20).collect();
    assert!(!after.is_empty());
    assert!(
        after.iter().filter(|r| r.tracked == Some(true)).count() * 10 >= after.len() * 8,
        "{after:?}"
    );
}
