//! `host-vision` as a user runs it: every command is a process, checked for its exit code and
//! what it says. One tiny dataset (1.5 s of desktop-fast at 160×120, made by `host-vision
//! synth`) serves every `track` run, so each takes about a second.
//!
//! The numbered tests follow issue 13's points.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod common;
use common::*;

/// Point 1: A failing link ends the process with its error, in order: never a crash (the renderer's
/// thread was torn down by the exit). The 200-run loop is in the issue's notes; ten here.
#[test]
fn p01_a_failing_link_exits_with_its_error_and_never_crashes() {
    let ds = dataset();
    let out = tmp("p01");
    for i in 0..10 {
        let (link, message) = if i % 2 == 0 {
            (
                "serial:/dev/nonexistent",
                "Error: cannot open serial device /dev/nonexistent at 921600 baud: No such file or directory\n",
            )
        } else {
            (
                "tcp:127.0.0.1:1",
                "Error: TCP connect to 127.0.0.1:1: Connection refused (os error 111): is the board (firmware-sim --link tcp:127.0.0.1:1) running, and free? It serves one host and exits, unless started with --forever\n",
            )
        };
        let (_, err) = expect(&track_args(&ds, &out, &["--link", link]), 1);
        assert_eq!(err, message);
    }
    let (_, err) = expect(&track_args(&ds, &out, &["--link", "tcp:"]), 2);
    assert!(
        err.contains("invalid value 'tcp:' for '--link <LINK>': `tcp:`: expected tcp:HOST:PORT"),
        "{err}"
    );
}

/// Point 2: Negative numbers are values; the range checks still refuse what is out of range.
#[test]
fn p02_negative_numbers_are_values() {
    let ds = dataset();
    let out = tmp("p02");
    // The dataset's own start pose (x is negative) given by hand.
    let d = frames::euroc::Dataset::open(&ds).unwrap();
    let (p, q) = d.groundtruth_at(d.imu[0].stamp).unwrap();
    let pos = format!("{},{},{}", p.x, p.y, p.z);
    let yaw = format!("{}", q.euler_angles().2.to_degrees());
    assert!(p.x < 0.0, "{pos}");
    let (so, _) = expect(
        &track_args(
            &ds,
            &out,
            &[
                "--start-position",
                &pos,
                "--start-yaw",
                &yaw,
                "--overlay-every",
                "0",
            ],
        ),
        0,
    );
    assert!(so.contains("from snap-on at"), "{so}");
    let (_, err) = expect(
        &track_args(
            &ds,
            &out,
            &["--overwrite", "--start-yaw", "-10", "--latency", "-1"],
        ),
        2,
    );
    assert_eq!(
        err,
        "Error: --latency must be a non-negative number of seconds, got -1\n"
    );
    let (_, err) = expect(
        &[
            "synth",
            "--scenario",
            "room",
            "--out",
            s(&out),
            "--duration",
            "-1",
        ],
        2,
    );
    assert!(!err.contains("unexpected argument"), "{err}");
    assert!(err.contains("-1"), "{err}");
}

/// Point 4: Earlier outputs are refused; `--overwrite` removes them first (runs never mix); an
/// output folder inside the dataset is refused. The same for `eval` and `demo`.
#[test]
fn p04_earlier_outputs_are_refused_unless_overwritten() {
    let ds = dataset();
    let out = tmp("p04");
    std::fs::create_dir_all(out.join("overlays")).unwrap();
    std::fs::write(out.join("summary.json"), "mine").unwrap();
    std::fs::write(out.join("overlays/frame_999999.png"), "old").unwrap();
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let (_, err) = expect(&track_args(&ds, &out, &[]), 1);
    assert_eq!(
        err,
        format!(
            "Error: output folder {} already holds summary.json, overlays/frame_*.png from an earlier run; choose another folder or pass --overwrite\n",
            out.display()
        )
    );
    assert_eq!(
        std::fs::read_to_string(out.join("summary.json")).unwrap(),
        "mine"
    );
    expect(&track_args(&ds, &out, &["--overwrite"]), 0);
    assert!(!out.join("overlays/frame_999999.png").exists());
    assert!(out.join("summary.json").metadata().unwrap().len() > 100);
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );

    let frames = std::fs::read(ds.join("frames.csv")).unwrap();
    for inside in [ds.clone(), ds.join("results")] {
        let (_, err) = expect(&track_args(&ds, &inside, &["--overwrite"]), 1);
        assert_eq!(
            err,
            format!(
                "Error: output folder {} is inside the dataset {}: choose a folder outside it\n",
                inside.display(),
                ds.display()
            )
        );
    }
    assert_eq!(std::fs::read(ds.join("frames.csv")).unwrap(), frames);
    assert!(!ds.join("results").exists());

    let eval_out = tmp("p04-eval");
    std::fs::create_dir_all(&eval_out).unwrap();
    std::fs::write(eval_out.join("eval.md"), "mine").unwrap();
    let cache = tmp("p04-cache");
    for cmd in ["eval", "demo"] {
        let (_, err) = expect(
            &[
                cmd,
                "--out",
                s(&eval_out),
                "--cache",
                s(&cache),
                "--duration",
                "1",
            ],
            1,
        );
        assert_eq!(
            err,
            format!(
                "Error: output folder {} already holds eval.md from an earlier run; choose another folder or pass --overwrite\n",
                eval_out.display()
            )
        );
    }
    assert!(!cache.exists(), "nothing synthesised before the refusal");
}

/// Point 5: An unusable output folder is named before anything is tracked.
#[test]
fn p05_an_unusable_output_folder_is_named_first() {
    let ds = dataset();
    let file = tmp("p05-file");
    std::fs::write(&file, "").unwrap();
    for (out, problem) in [
        ("/dev/null", "exists and is not a directory"),
        (s(&file), "exists and is not a directory"),
        ("/proc/1", "not writable: "),
    ] {
        let (so, err) = expect(&track_args(&ds, Path::new(out), &[]), 1);
        assert!(
            err.starts_with(&format!("Error: output folder {out}: {problem}")),
            "{err}"
        );
        assert!(so.is_empty(), "tracked before the check: {so}");
    }
}

/// Point 6: `track` refuses what `synth` and `eval` refuse, naming the flag.
#[test]
fn p06_out_of_range_values_are_refused() {
    let ds = dataset();
    let out = tmp("p06");
    for (args, message) in [
        (
            vec!["--duration", "0"],
            "--duration must be a number of seconds longer than the core's 0.30 s initialisation, got 0",
        ),
        (
            vec!["--duration", "-1"],
            "--duration must be a number of seconds longer than the core's 0.30 s initialisation, got -1",
        ),
        (
            vec!["--duration", "nan"],
            "--duration must be a number of seconds longer than the core's 0.30 s initialisation, got NaN",
        ),
        (vec!["--features", "0"], "--features must be at least 1"),
        (
            vec!["--latency", "1"],
            "--latency 1 s must be below one frame period (0.040 s): each prediction needs the previous frame's update",
        ),
        (
            vec!["--corrupt-at", "-5"],
            "--corrupt-at counts seconds from the dataset's first IMU sample and must lie in the tracked span [0, 1.50) s, got -5",
        ),
        (
            vec!["--corrupt-at", "9"],
            "--corrupt-at counts seconds from the dataset's first IMU sample and must lie in the tracked span [0, 1.50) s, got 9",
        ),
        (
            vec!["--outliers", "1.5"],
            "--outliers must be a fraction in [0, 1], got 1.5",
        ),
        (
            vec!["--reset-core-at", "1", "--link", "tcp:127.0.0.1:9"],
            "--reset-core-at needs a core the host can reset: --link sim, inproc or qemu, not tcp 127.0.0.1:9",
        ),
        (
            vec!["--cut-link-at", "-1"],
            "--cut-link-at counts seconds from the start and must be at least 0, got -1",
        ),
    ] {
        let (so, err) = expect(&track_args(&ds, &out, &args), 2);
        assert_eq!(err, format!("Error: {message}\n"), "{args:?}");
        assert!(so.is_empty());
    }
    assert!(!out.exists(), "a refused run made its folder");
    let (_, err) = expect(&["eval", "--duration", "0", "--out", s(&out)], 2);
    assert!(
        err.contains(
            "invalid value '0' for '--duration <DURATION>': must be a positive number of seconds"
        ),
        "{err}"
    );
}

/// Point 7: A run that never locks on says so and exits 3 (documented in `--help`).
#[test]
fn p07_a_run_that_never_starts_tracking_exits_3() {
    let ds = dataset();
    let out = tmp("p07");
    let (so, err) = expect(&track_args(&ds, &out, &["--start-position", "1,2,3"]), 3);
    assert!(
        so.contains(
            "tracked      never: the core accepted no correspondence, tracking never started"
        ),
        "{so}"
    );
    assert!(
        so.contains("accuracy     n/a (tracking never started)"),
        "{so}"
    );
    assert!(
        err.starts_with("tracking never started: the core accepted none of the"),
        "{err}"
    );
    let (help, _) = expect(&["--help"], 0);
    assert!(
        help.contains(
            "3 nothing found (track: the core accepted no correspondence, tracking never started"
        ),
        "{help}"
    );
}

/// Point 8: A closed stdout (`| head -1`) is no panic: the run goes on and writes its files.
#[test]
fn p08_a_closed_stdout_is_not_a_panic() {
    let ds = dataset();
    let out = tmp("p08");
    for args in [
        vec!["selftest", "--imu-samples", "200"],
        track_args(&ds, &out, &[]),
    ] {
        let mut child = Command::new(HV)
            .args(&args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let result = child.wait_with_output().unwrap();
        let err = text(&result.stderr);
        assert_eq!(result.status.code(), Some(0), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    assert!(out.join("summary.json").is_file());
}

/// Point 9: Each cause of an error is said once, without a backtrace.
#[test]
fn p09_each_cause_is_said_once() {
    let ds = dataset();
    let out = tmp("p09");
    let run = Command::new(HV)
        .args(track_args(&ds, &out, &["--link", "tcp:127.0.0.1:1"]))
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    let err = text(&run.stderr);
    assert_eq!(run.status.code(), Some(1));
    assert_eq!(count(&err, "Connection refused"), 1, "{err}");
    assert!(
        !err.contains("Caused by") && !err.contains("backtrace"),
        "{err}"
    );
    let (_, err) = expect(&track_args(Path::new("/nonexistent"), &out, &[]), 1);
    assert_eq!(err, "Error: /nonexistent: missing (dataset folder)\n");
}

/// Point 10: No internal debug text: links described, no build-machine path in the binary, flags
/// named, JSON figures rounded.
#[test]
fn p10_no_internal_debug_text() {
    let ds = dataset();
    let out = tmp("p10");
    let (so, _) = expect(&track_args(&ds, &out, &[]), 0);
    assert!(
        so.contains("link sim (f32 core in this process, on a pty pair)"),
        "{so}"
    );
    assert!(!so.contains("Sim(") && !so.contains("F32"), "{so}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(
        summary["link"],
        "sim (f32 core in this process, on a pty pair)"
    );
    let mut floats = Vec::new();
    collect_floats(&summary, &mut floats);
    assert!(floats.len() > 10);
    for x in floats {
        let rounded: f64 = format!("{x:.8e}").parse().unwrap();
        assert_eq!(x, rounded, "{x} has more than 9 significant digits");
    }
    let (_, err) = expect(
        &track_args(&ds, &out, &["--overwrite", "--angular-noise", "-1"]),
        2,
    );
    assert_eq!(
        err,
        "Error: --angular-noise must be a positive number [rad/s²/√Hz], got -1\n"
    );
    let binary = std::fs::read(HV).unwrap();
    let baked = b"host-vision/../firmware";
    assert!(
        !binary.windows(baked.len()).any(|w| w == baked),
        "a build-machine path is baked into the binary"
    );
    // Without an image near the current folder or the program, `qemu` says where it looked.
    // (Beside the program is the repository's image, once `cargo xtask firmware` built it:
    // then that one is used.)
    let beside = std::path::Path::new(HV).ancestors().any(|a| {
        a.join("firmware/target/thumbv7em-none-eabihf/release/device")
            .is_file()
    });
    let run = Command::new(HV)
        .args(track_args(&ds, &out, &["--overwrite", "--link", "qemu"]))
        .current_dir("/")
        .output()
        .unwrap();
    if beside {
        assert_eq!(run.status.code(), Some(0), "{}", text(&run.stderr));
        return;
    }
    assert_eq!(run.status.code(), Some(1));
    let err = text(&run.stderr);
    assert!(
        err.contains("no firmware image firmware/target/thumbv7em-none-eabihf/release/device in the current folder, beside this program, or above either; build it with `cargo xtask firmware`")
            || err.contains("qemu-system-arm"),
        "{err}"
    );
}

fn collect_floats(v: &serde_json::Value, out: &mut Vec<f64>) {
    match v {
        serde_json::Value::Number(n) if n.is_f64() => out.push(n.as_f64().unwrap()),
        serde_json::Value::Array(a) => a.iter().for_each(|x| collect_floats(x, out)),
        serde_json::Value::Object(o) => o.values().for_each(|x| collect_floats(x, out)),
        _ => {}
    }
}

/// Point 11: The help says what each option means; no silent default without ground truth.
#[test]
fn p11_help_texts_agree_and_the_start_pose_is_required_without_ground_truth() {
    let (track, _) = expect(&["track", "--help"], 0);
    for phrase in [
        "--accel-meas-noise <ACCEL_MEAS_NOISE>",
        "a standard deviation per sample [m/s²]",
        "Not synth's --accel-noise, which is the sensor's noise density",
        "Start yaw of the IMU [deg] (default: from the ground truth; without one, give it with --start-position, or neither for the cold start)",
        "serial:PATH[@BAUD]",
        "BAUD defaults to 921600",
        "tcp:HOST:PORT",
        "qemu:IMAGE",
        "counted from the dataset's first IMU sample as frames.csv's t_s",
    ] {
        assert!(
            track.contains(phrase),
            "track --help lacks `{phrase}`:\n{track}"
        );
    }
    assert!(!track.contains("--accel-noise <"), "{track}");
    let (synth, _) = expect(&["synth", "--help"], 0);
    assert!(
        synth.contains("Accelerometer white-noise density of the simulated sensor [m/s²/√Hz]"),
        "{synth}"
    );

    let ds = dataset();
    let bare = tmp("p11-no-groundtruth");
    copy_dir(&ds, &bare, "state_groundtruth_estimate0");
    let out = tmp("p11");
    let (_, err) = expect(&track_args(&bare, &out, &["--start-position", "0,0,0"]), 2);
    assert_eq!(
        err,
        "Error: the dataset has no ground truth: give both --start-position and --start-yaw, or --start-pose, or neither (the cold start then finds the model)\n"
    );
}

/// Point 12: No leftovers: a failed link leaves no output folder; a file for a dataset is named.
#[test]
fn p12_no_leftovers_and_a_file_is_not_a_dataset() {
    let ds = dataset();
    let out = tmp("p12").join("new/deeper");
    let (_, err) = expect(
        &track_args(&ds, &out, &["--link", "serial:/dev/nonexistent"]),
        1,
    );
    assert!(err.contains("/dev/nonexistent"), "{err}");
    assert!(
        !out.parent().unwrap().exists(),
        "a failed run left its folder"
    );
    let manifest = ds.join("manifest.json");
    let (_, err) = expect(&track_args(&manifest, &out, &[]), 1);
    assert_eq!(
        err,
        format!(
            "Error: {}: is a file, not a dataset folder (the folder holding mav0/)\n",
            manifest.display()
        )
    );
}

/// Point 13: Ctrl-C in `eval` and `demo` behaves as in `track`: a message, exit 130, what was done
/// written, no empty folders; `eval` prints a line per finished run without a terminal.
#[test]
fn p13_ctrl_c_in_eval_and_demo_writes_what_was_done() {
    let out = tmp("p13-eval");
    let cache = tmp("p13-cache");
    // The first run's line comes while room is still to be synthesised: Ctrl-C lands there.
    let (code, printed, err) = signal_when(
        &[
            "eval",
            "--scenario",
            "desktop-slow",
            "--scenario",
            "room",
            "--filter",
            "acc",
            "--duration",
            "2",
            "--no-two-features",
            "--out",
            s(&out),
            "--cache",
            s(&cache),
        ],
        "done: desktop-slow acc model",
        "INT",
        Duration::ZERO,
    );
    assert_eq!(code, Some(130), "{printed}\n{err}");
    assert!(
        printed.contains("interrupted: wrote the runs done"),
        "{printed}"
    );
    let md = std::fs::read_to_string(out.join("eval.md")).unwrap();
    assert!(md.contains("| desktop-slow |"), "{md}");
    assert!(!md.contains("| room |"), "{md}");
    assert!(!out.join("room").exists());
    let cached: Vec<_> = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert_eq!(
        cached,
        ["desktop-slow-2s-seed0"],
        "a half-made dataset stayed"
    );

    // Ctrl-C during the demo's synthesis: nothing was done, nothing stays.
    let out = tmp("p13-demo");
    let cache = tmp("p13-demo-cache");
    let (code, printed, err) = signal_when(
        &[
            "demo",
            "--duration",
            "3",
            "--out",
            s(&out),
            "--cache",
            s(&cache),
        ],
        "demo: desktop-fast",
        "INT",
        Duration::ZERO,
    );
    assert_eq!(code, Some(130), "{printed}\n{err}");
    assert!(
        printed.contains("interrupted before any run finished: nothing written"),
        "{printed}"
    );
    assert!(!out.exists(), "an empty output folder was left");
    // The signal may land after the synthesis under load: a finished dataset may stay in the
    // cache (it is one), a half-made one never.
    if cache.exists() {
        for entry in std::fs::read_dir(&cache).unwrap() {
            let dir = entry.unwrap().path();
            assert!(
                dir.join("manifest.json").is_file(),
                "half-made dataset {}",
                dir.display()
            );
        }
    }
}

/// Point 14: One time base per file, as the README says; the ground truth cut to the span tracked.
#[test]
fn p14_time_bases_and_the_tracked_span() {
    let ds = dataset();
    let out = tmp("p14");
    expect(&track_args(&ds, &out, &["--duration", "1"]), 0);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let t0 = summary["t0_stamp_ns"].as_u64().unwrap();
    let tum = |name: &str| -> Vec<f64> {
        std::fs::read_to_string(out.join(name))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(|l| l.split(' ').next().unwrap().parse().unwrap())
            .collect()
    };
    let gt = tum("groundtruth.tum");
    let t0_s = t0 as f64 / 1e9;
    assert_eq!(gt.len(), 101, "1 s at 100 Hz");
    assert!((gt[0] - t0_s).abs() < 1e-6 && (gt[100] - t0_s - 1.0).abs() < 1e-6);
    // frames.csv's t_s counts from t0: the frames' TUM stamps are t0 + t_s (the predicted
    // ones: the frames before the core's initialisation ended have rows without a pose).
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    let first: f64 = frame_rows(&out)
        .iter()
        .find(|r| r["outcome"] == "analysed")
        .unwrap()["t_s"]
        .parse()
        .unwrap();
    assert!((tum("trajectory_frames.tum")[0] - (t0_s + first)).abs() < 1e-6);
    let (duration, snap, tracked) = (
        summary["duration_s"].as_f64().unwrap(),
        summary["snapped_on_at"].as_f64().unwrap(),
        summary["tracked_s"].as_f64().unwrap(),
    );
    assert_eq!(duration, 1.0);
    assert!(
        (tracked - (duration - snap)).abs() < 1e-9,
        "{tracked} {snap}"
    );

    // The README documents every column and every field.
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"))
            .unwrap();
    let columns = csv.lines().next().unwrap().split(',');
    let fields = summary.as_object().unwrap().keys().map(String::as_str);
    for name in columns.chain(fields) {
        assert!(
            readme.contains(&format!("`{name}`")),
            "README does not document `{name}`"
        );
    }
}

/// Point 15: Quiet, labelled progress: no Mesa noise without XDG_RUNTIME_DIR, the self-test's
/// deliberate refusal labelled, counts in the right number. (The bars' widths are checked in
/// the binary's own tests.)
#[test]
fn p15_progress_and_noise() {
    let ds = dataset();
    let out = tmp("p15");
    let run = Command::new(HV)
        .args(track_args(&ds, &out, &[]))
        .env_remove("XDG_RUNTIME_DIR")
        .output()
        .unwrap();
    let (so, err) = (text(&run.stdout), text(&run.stderr));
    assert_eq!(run.status.code(), Some(0), "{err}");
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
    // 30 frames from index 8: one (index 25) at every 25th.
    assert!(so.contains("(1 overlay image)"), "{so}");
    let (so, _) = expect(&["selftest", "--imu-samples", "200"], 0);
    assert!(
        so.contains("test step, refused on purpose: a host of another major version"),
        "{so}"
    );
}

/// Flags (`--name`) in `text`.
fn flags(text: &str) -> impl Iterator<Item = &str> {
    text.split(|c: char| !(c.is_ascii_alphanumeric() || c == '-'))
        .filter(|w| w.starts_with("--") && w.len() > 2)
}

/// The README's commands name only flags their `--help` has: in its command blocks per
/// subcommand (continuation lines start with `[`), in its prose (`--flag` in backticks) in
/// some subcommand's.
#[test]
fn readme_commands_name_only_real_flags() {
    const SUBS: [&str; 7] = [
        "track", "eval", "demo", "synth", "selftest", "frames", "locate",
    ];
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"))
            .unwrap();
    let help: std::collections::BTreeMap<&str, String> = SUBS
        .iter()
        .map(|&sub| (sub, expect(&[sub, "--help"], 0).0))
        .collect();
    let has = |sub: &str, flag: &str| {
        let h = &help[sub];
        h.contains(&format!("{flag} ")) || h.contains(&format!("{flag}\n"))
    };
    let (mut in_code, mut current, mut checked) = (false, None, 0);
    for line in readme.lines() {
        if line.starts_with("```") {
            in_code = !in_code;
            current = None;
            continue;
        }
        if in_code {
            let mut code = line.split(" #").next().unwrap_or("");
            if let Some(rest) = code.split("host-vision -- ").nth(1) {
                current = rest.split_whitespace().next().filter(|w| SUBS.contains(w));
                code = rest;
            } else if !code.trim_start().starts_with('[') {
                current = None;
            }
            if let Some(sub) = current {
                for flag in flags(code) {
                    assert!(
                        has(sub, flag),
                        "README: `host-vision {sub} {flag}` is not in its --help"
                    );
                    checked += 1;
                }
            }
        } else {
            for span in line.split('`').skip(1).step_by(2) {
                for flag in flags(span).filter(|_| span.starts_with("--")) {
                    assert!(
                        SUBS.iter().any(|sub| has(sub, flag)),
                        "README: `{flag}` is not in any subcommand's --help"
                    );
                    checked += 1;
                }
            }
        }
    }
    assert!(checked >= 40, "only {checked} flags found in the README");
}

/// Issue 14: `--start-pose` gives the core a full 6-DoF start. The ground truth's camera pose
/// at the first IMU sample, written as a `cMo` JSON, snaps on as the ground truth does; the
/// same pose as a TUM line (the first line of the run's own groundtruth.tum) snaps on without
/// any ground truth in the dataset; the pose 0.3 m off never does (so the file is what counts).
#[test]
fn p16_a_start_pose_file_snaps_on_as_the_ground_truth() {
    use host_vision::camera::CameraPose;
    let ds = dataset();
    let base = tmp("p16-gt");
    expect(&track_args(&ds, &base, &["--overlay-every", "0"]), 0);
    let gt = summary(&base);

    let d = frames::euroc::Dataset::open(&ds).unwrap();
    let (s_w, q_ws) = d.groundtruth_at(d.imu[0].stamp).unwrap();
    let (c_w, q_cw) = d.hand_eye.camera_pose(&s_w, &q_ws);
    let json = tmp("p16-pose.json");
    std::fs::write(
        &json,
        host_vision::start_pose::start_pose_json(&CameraPose { q_cw, c_w }),
    )
    .unwrap();
    let out = tmp("p16-json");
    expect(
        &track_args(
            &ds,
            &out,
            &["--overlay-every", "0", "--start-pose", s(&json)],
        ),
        0,
    );
    let with_pose = summary(&out);
    let snap = |v: &serde_json::Value| v["snapped_on_at"].as_f64().unwrap();
    assert!(
        (snap(&with_pose) - snap(&gt)).abs() <= 0.05,
        "snapped on at {} with --start-pose, {} with the ground truth",
        snap(&with_pose),
        snap(&gt)
    );
    let err = |v: &serde_json::Value| v["accuracy"]["mean_position_m"].as_f64().unwrap();
    assert!(
        err(&with_pose) < 2.0 * err(&gt) + 0.005,
        "mean position error {} m with --start-pose, {} m with the ground truth",
        err(&with_pose),
        err(&gt)
    );

    let no_gt = tmp("p16-no-gt");
    copy_dir(&ds, &no_gt, "state_groundtruth_estimate0");
    let first_line = std::fs::read_to_string(base.join("groundtruth.tum"))
        .unwrap()
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .to_owned();
    let tum = tmp("p16-pose.tum");
    std::fs::write(&tum, format!("{first_line}\n")).unwrap();
    let out = tmp("p16-tum");
    expect(
        &track_args(
            &no_gt,
            &out,
            &["--overlay-every", "0", "--start-pose", s(&tum)],
        ),
        0,
    );
    assert!((snap(&summary(&out)) - snap(&gt)).abs() <= 0.05);

    let mut v: Vec<f64> = first_line
        .split_whitespace()
        .map(|w| w.parse().unwrap())
        .collect();
    v[1] += 0.3;
    let off: Vec<String> = v.iter().map(f64::to_string).collect();
    std::fs::write(&tum, off.join(" ")).unwrap();
    let out = tmp("p16-off");
    let (_, se) = expect(
        &track_args(
            &no_gt,
            &out,
            &["--overlay-every", "0", "--start-pose", s(&tum)],
        ),
        3,
    );
    assert!(se.contains("--start-pose"), "{se}");
}

/// Issue 14: a start pose that is not a rigid transform, or not a pose file at all, is
/// refused with the flag and the reason (exit 2), before anything runs or is written.
#[test]
fn p17_a_non_rigid_start_pose_is_refused_with_the_flag() {
    let ds = dataset();
    let cases = [
        (
            r#"{"cMo": [[1.1,0,0,0],[0,1,0,0],[0,0,1,0.5],[0,0,0,1]]}"#,
            "cMo is not a rigid transform: the rotation is not orthonormal",
        ),
        (
            r#"{"cMo": [[-1,0,0,0],[0,1,0,0],[0,0,1,0.5],[0,0,0,1]]}"#,
            "determinant is -1.000000, not +1",
        ),
        (
            r#"{"cMo": [[1,0,0,0],[0,1,0,0],[0,0,1,0.5],[0,0,1,1]]}"#,
            "the last row is [0, 0, 1, 1]",
        ),
        (r#"{"pose": []}"#, "JSON without a `cMo` field"),
        ("0 1 2 3 0 0 0.5 2", "quaternion has norm 2.06"),
        ("0 1 2", "a TUM line has 8 numbers"),
    ];
    for (i, (text, reason)) in cases.iter().enumerate() {
        let pose = tmp(&format!("p17-pose-{i}"));
        std::fs::write(&pose, text).unwrap();
        let out = tmp(&format!("p17-{i}"));
        let (_, se) = expect(&track_args(&ds, &out, &["--start-pose", s(&pose)]), 2);
        assert!(
            se.contains(&format!("--start-pose {}: ", pose.display())) && se.contains(reason),
            "{text}: {se}"
        );
        assert!(!out.exists(), "nothing written for {text}");
    }
    let out = tmp("p17-missing");
    let (_, se) = expect(
        &track_args(&ds, &out, &["--start-pose", "/nonexistent/pose.json"]),
        2,
    );
    assert!(
        se.contains("--start-pose /nonexistent/pose.json: cannot read"),
        "{se}"
    );
}

/// Issue 14: inputs without an IMU are tracked vision-only, and say so: a dataset without
/// `imu0` (from its ground truth), its `cam0` as `--images` (with `--start-pose` and the
/// camera given); an inertial model on them is refused; missing intrinsics and missing files
/// are named, and nothing is written.
#[test]
fn p18_inputs_without_an_imu_are_tracked_vision_only() {
    let no_imu = without_imu("p18-no-imu");
    let out = tmp("p18-out");
    let (so, se) = expect(&track_args(&no_imu, &out, &["--overlay-every", "0"]), 0);
    assert!(
        se.contains("no IMU: tracking vision-only (--filter vision)"),
        "{se}"
    );
    assert!(so.contains("(vision-only: no IMU used)"), "{so}");
    let sum = summary(&out);
    assert_eq!(sum["model"], "vision");
    assert_eq!(sum["imu_used"], false);
    assert!(sum["tracked"]["frames"].as_u64().unwrap() > 20, "{sum}");
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    let header = csv.lines().next().unwrap();
    assert!(
        header.contains(",rms_px,consistency,ncc,tracked,age_ms,sent_ms,pose_ms,dropped_before,")
            && header.ends_with(",weakest,weakest_sigma,nees,cov_00,cov_01,cov_02,cov_03,cov_04,cov_05,cov_11,cov_12,cov_13,cov_14,cov_15,cov_22,cov_23,cov_24,cov_25,cov_33,cov_34,cov_35,cov_44,cov_45,cov_55,outcome"),
        "{header}"
    );
    // Every analysed frame's pose has its covariance, as wide as the header.
    let rows = frame_rows(&out);
    let analysed: Vec<_> = rows.iter().filter(|r| r["outcome"] == "analysed").collect();
    assert!(!analysed.is_empty());
    for r in &analysed {
        let sigma: f64 = r["sigma_pos_m"].parse().unwrap();
        assert!(sigma > 0.0 && sigma < 0.5, "{sigma}");
        assert!(!r["weakest"].is_empty() && !r["cov_55"].is_empty());
    }

    // An inertial model needs the IMU.
    let out2 = tmp("p18-acc");
    let (_, se) = expect(&track_args(&no_imu, &out2, &["--filter", "acc"]), 1);
    assert!(
        se.contains("missing (IMU samples): the acc model needs an IMU; `--filter vision` tracks the camera alone"),
        "{se}"
    );
    assert!(!out2.exists());

    // The camera folder as --images: the intrinsics and the start pose must be given.
    let cam0 = no_imu.join("mav0/cam0");
    let (_, se) = expect(&["track", "--images", s(&cam0), "--out", s(&out2)], 2);
    assert!(
        se.contains("give the camera's intrinsics: --camera camera.json, --calib (Kalibr or EuRoC YAML) or --intrinsics fx,fy,cx,cy"),
        "{se}"
    );
    assert!(!out2.exists());
    let (_, se) = expect(
        &["track", "--video", "/nonexistent.mp4", "--out", s(&out2)],
        1,
    );
    assert!(
        se.contains("/nonexistent.mp4: no such file or folder"),
        "{se}"
    );
    // Issue 33, point 11: a missing input is not first said to have no IMU.
    assert!(!se.contains("no IMU"), "{se}");
    assert!(!out2.exists());
    // The frames themselves are readable.
    let (so, _) = expect(&["frames", "--images", s(&cam0)], 0);
    assert!(so.contains("frames:        38 of 160x120 px"), "{so}");
}

/// Issue 14: bad vision-only input is named, before anything is written: a file ffmpeg cannot
/// decode, a camera for another frame size, a malformed camera file, a start pose that is not
/// rigid.
#[test]
fn p19_bad_vision_only_input_is_named_and_nothing_is_written() {
    let ds = dataset();
    let cam0 = ds.join("mav0/cam0");
    let pose = tmp("p19-pose.json");
    std::fs::write(
        &pose,
        r#"{"cMo": [[1,0,0,0],[0,1,0,0],[0,0,1,0.5],[0,0,0,1]]}"#,
    )
    .unwrap();
    let camera = |name: &str, w: u32, h: u32| {
        let p = tmp(name);
        std::fs::write(
            &p,
            format!(
                r#"{{"model": "pinhole", "width": {w}, "height": {h}, "fx": 100, "fy": 100, "cx": {}, "cy": {}, "distortion": "none"}}"#,
                w / 2,
                h / 2
            ),
        )
        .unwrap();
        p
    };
    let out = tmp("p19-out");
    let model = ds.join("model/scene.obj");
    let vision = |input: &[&str], cam: &Path, pose: &Path| -> Vec<String> {
        let mut a: Vec<String> = vec!["track".into()];
        a.extend(input.iter().map(|v| v.to_string()));
        for (flag, v) in [
            ("--camera", s(cam)),
            ("--model", s(&model)),
            ("--start-pose", s(pose)),
            ("--out", s(&out)),
        ] {
            a.push(flag.into());
            a.push(v.into());
        }
        a
    };
    let run = |args: Vec<String>, code: i32| {
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        let (_, se) = expect(&refs, code);
        assert!(!out.exists(), "outputs were written:\n{se}");
        se
    };
    // A camera for 640x480 frames, with 160x120 frames.
    let wrong = camera("p19-camera-640.json", 640, 480);
    let se = run(vision(&["--images", s(&cam0)], &wrong, &pose), 2);
    assert!(
        se.contains("the frames are 160x120 pixels, the camera's intrinsics are for 640x480"),
        "{se}"
    );
    // A camera file that is not one.
    let broken = tmp("p19-camera-broken.json");
    std::fs::write(&broken, "{\"model\": \"pinhole\", \"width\": 160").unwrap();
    let se = run(vision(&["--images", s(&cam0)], &broken, &pose), 1);
    assert!(se.contains("p19-camera-broken.json"), "{se}");
    // A video ffmpeg cannot decode.
    let right = camera("p19-camera-160.json", 160, 120);
    let junk = tmp("p19-junk.mp4");
    std::fs::write(&junk, b"not a video, just bytes that end early").unwrap();
    let se = run(vision(&["--video", s(&junk)], &right, &pose), 1);
    assert!(se.contains("p19-junk.mp4: ffmpeg cannot decode it"), "{se}");
    // A start pose that is not rigid.
    let skew = tmp("p19-skew.json");
    std::fs::write(
        &skew,
        r#"{"cMo": [[1,0.2,0,0],[0,1,0,0],[0,0,1,0.5],[0,0,0,1]]}"#,
    )
    .unwrap();
    let se = run(vision(&["--images", s(&cam0)], &right, &skew), 2);
    assert!(se.contains("is not a rigid transform"), "{se}");
}

#[test]
fn p20_locate_finds_the_model_in_a_frame_and_names_bad_input() {
    let ds = dataset();
    let cam0 = ds.join("mav0/cam0");
    let mut frames: Vec<PathBuf> = std::fs::read_dir(cam0.join("data"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    frames.sort();
    let (calib, model) = (cam0.join("sensor.yaml"), ds.join("model/scene.obj"));
    let (cache, out) = (tmp("p20-cache"), tmp("p20-out"));
    let locate = |extra: &[&str], code: i32| {
        let mut a = vec![
            "locate",
            "--image",
            s(&frames[0]),
            "--calib",
            s(&calib),
            "--model",
            s(&model),
            "--cache",
            s(&cache),
            "--out",
            s(&out),
        ];
        a.extend_from_slice(extra);
        expect(&a, code)
    };
    let (so, _) = locate(&[], 0);
    for line in ["database", "attempt", "verified", "pose"] {
        assert!(so.contains(line), "{so}");
    }
    assert!(
        so.contains("built"),
        "the first run builds the database: {so}"
    );
    assert!(out.join("locate.json").exists());
    // Again: refused without --overwrite, then the cached database.
    let (_, se) = locate(&[], 1);
    assert!(se.contains("--overwrite"), "{se}");
    let (so, _) = locate(&["--overwrite"], 0);
    assert!(so.contains("cached"), "{so}");
    // No camera; a missing image.
    let (_, se) = expect(
        &[
            "locate",
            "--image",
            s(&frames[0]),
            "--model",
            s(&model),
            "--out",
            s(&out),
        ],
        2,
    );
    assert!(se.contains("--camera"), "{se}");
    let missing = tmp("p20-none.png");
    let (_, se) = expect(
        &[
            "locate",
            "--image",
            s(&missing),
            "--calib",
            s(&calib),
            "--model",
            s(&model),
            "--out",
            s(&tmp("p20-out2")),
        ],
        1,
    );
    assert!(se.contains("p20-none.png"), "{se}");
}

// Issue 33: the second new-user walkthrough. One test per point done so far.

/// Issue 33, point 3: a link that never came back before the input ended exited 0 with
/// `stopped_early: false, error: null`: only 4.9–6.9 of 15 s were tracked. An unresolved
/// outage is a failed run: exit 1, the error on stderr and in the summary, and what was
/// tracked before it written.
#[test]
fn i33_p03_an_outage_the_input_outlasts_fails_the_run() {
    let ds = dataset();
    let out = tmp("i33-p03");
    let (_, err) = expect(
        &track_args(&ds, &out, &["--cut-link-at", "0.6", "--cut-seconds", "30"]),
        1,
    );
    assert!(
        err.starts_with("Error: core: link ")
            && err.contains("the core was not reached again before the input ended"),
        "{err}"
    );
    let sum = summary(&out);
    assert_eq!(sum["stopped_early"], true, "{sum}");
    assert!(
        sum["error"]
            .as_str()
            .is_some_and(|e| e.contains("not reached again before the input ended")),
        "{sum}"
    );
    assert_eq!(sum["outages"][0]["kind"], "unresolved", "{sum}");
    // A cut the link comes back from still ends well.
    let back = tmp("i33-p03-back");
    expect(
        &track_args(
            &ds,
            &back,
            &["--cut-link-at", "0.6", "--cut-seconds", "0.2"],
        ),
        0,
    );
}

/// Issue 33, point 5: `--features 100000000000` crashed on a 2.4 TB allocation (exit 134)
/// and left an empty `--out`; `--features 100000000` ran at 2.4 GB. What one frame can send
/// the core bounds it: beyond, exit 2 with the flag named, and nothing made.
#[test]
fn i33_p05_features_beyond_a_frame_are_refused() {
    let ds = dataset();
    for n in ["129", "100000000", "100000000000"] {
        let out = tmp("i33-p05");
        let (_, err) = expect(&track_args(&ds, &out, &["--features", n]), 2);
        assert_eq!(
            err,
            format!(
                "Error: --features must be at most 128 (the correspondences one frame can send to the core), got {n}\n"
            )
        );
        assert!(!out.exists(), "--features {n}: {} was made", out.display());
    }
    let out = tmp("i33-p05-max");
    expect(&track_args(&ds, &out, &["--features", "128"]), 0);
}

/// Issue 33, point 7: two runs into one `--out` both exited 0 and the folder held one run's
/// results. The first run holds the folder; a second one is refused while it does (exit 1,
/// the folder named), and the first one's results are whole.
#[test]
fn i33_p07_a_second_run_into_a_busy_folder_is_refused() {
    let ds = dataset();
    let out = tmp("i33-p07");
    let args = track_args(&ds, &out, &["--pacing", "real-time"]);
    let mut first = Command::new(HV)
        .args(&args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let lock = out.join(".host-vision.lock");
    let t0 = Instant::now();
    while !lock.exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "the first run never took the folder"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let (_, err) = expect(&track_args(&ds, &out, &["--overwrite"]), 1);
    assert_eq!(
        err,
        format!(
            "Error: output folder {}: another run is writing into it (it holds the lock .host-vision.lock); wait for that run or choose another folder\n",
            out.display()
        )
    );
    let status = first.wait().unwrap();
    let mut first_err = String::new();
    std::io::Read::read_to_string(&mut first.stderr.take().unwrap(), &mut first_err).unwrap();
    assert!(status.success(), "the first run: {first_err}");
    assert!(summary(&out)["frames"].as_u64().unwrap() > 0);
    assert!(!lock.exists(), "the lock's file went with the run");
}

/// Issue 33, point 9: an untextured model with a start pose ran for 0.5 s with nothing
/// accepted, then failed with "cold start: …" though no cold start was asked for. Asked to
/// register its texture, it is refused before anything runs, with the reason that applies,
/// and nothing is written (issue 37: by default such a model is tracked by its contour); and
/// asked to find it without a start pose, too (the cold start finds models by their texture).
#[test]
fn i33_p09_an_untextured_model_is_refused_up_front() {
    let ds = dataset();
    let model = tmp("i33-p09-model");
    copy_dir(&ds.join("model"), &model, "");
    let mtl = std::fs::read_to_string(model.join("scene.mtl")).unwrap();
    let plain: String = mtl
        .lines()
        .filter(|l| !l.starts_with("map_Kd"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(model.join("scene.mtl"), plain).unwrap();
    let obj = model.join("scene.obj");
    let out = tmp("i33-p09");
    let (_, err) = expect(
        &track_args(&ds, &out, &["--model", s(&obj), "--modality", "texture"]),
        1,
    );
    assert_eq!(
        err,
        format!(
            "Error: {}: the model has no textured material (an MTL without map_Kd, or a glTF material without a base colour texture): the texture modality registers the model's texture, so an untextured model gives it nothing to follow; track it by its contour (--modality contour, or auto)\n",
            obj.display()
        )
    );
    assert!(!err.contains("cold start"));
    assert!(!out.exists(), "nothing written");
    let (_, err) = expect(
        &track_args(&ds, &out, &["--model", s(&obj), "--cold-start"]),
        1,
    );
    assert_eq!(
        err,
        format!(
            "Error: {}: the model has no textured material, and no start pose was given: the cold start finds a model by its texture, so an untextured model is tracked by its contour from a start pose (--start-pose, --start-position/--start-yaw, or the dataset's ground truth)\n",
            obj.display()
        )
    );
    assert!(!out.exists(), "nothing written");
}

/// Issue 37: `synth --untextured-colour` takes a linear RGB colour in [0, 1], only with
/// `--untextured`; anything else is a usage error naming the flag, and nothing is written.
#[test]
fn i37_an_untextured_colour_out_of_range_or_without_untextured_is_a_usage_error() {
    let out = tmp("i37-colour");
    for bad in ["2,0,0", "0.1,0.2", "NaN,0,0", "-0.1,0.5,0.5"] {
        let (_, se) = expect(
            &[
                "synth",
                "--scenario",
                "desktop-fast",
                "--untextured",
                "--untextured-colour",
                bad,
                "--out",
                s(&out),
            ],
            2,
        );
        assert!(
            se.contains(&format!("invalid value '{bad}' for '--untextured-colour")),
            "{se}"
        );
    }
    let (_, se) = expect(
        &[
            "synth",
            "--scenario",
            "desktop-fast",
            "--untextured-colour",
            "0.1,0.1,0.3",
            "--out",
            s(&out),
        ],
        2,
    );
    assert!(se.contains("--untextured"), "{se}");
    assert!(!out.exists(), "nothing written");
}

/// Issue 33, point 11: values out of range are usage errors (exit 2) with the flag named,
/// before anything runs, whichever input they come with: `--fps 0`, `1e9` and `NaN` exited 1
/// from the image folder; `--latency -1` was accepted by a vision-only run; `eval --duration
/// 0.2` ran every inertial run without ever snapping on, and exited 0.
#[test]
fn i33_p11_out_of_range_values_are_usage_errors_for_every_input() {
    let ds = dataset();
    let cam0 = ds.join("mav0/cam0");
    let out = tmp("i33-p11");
    for fps in ["0", "1e9", "NaN", "-3"] {
        let (_, se) = expect(&["frames", "--images", s(&cam0), "--fps", fps], 2);
        assert!(
            se.contains(&format!(
                "invalid value '{fps}' for '--fps <FPS>': a frame rate in (0, 10000] Hz, got {fps}"
            )),
            "{se}"
        );
        let (_, se) = expect(
            &[
                "track",
                "--images",
                s(&cam0),
                "--fps",
                fps,
                "--out",
                s(&out),
            ],
            2,
        );
        assert!(se.contains("for '--fps <FPS>'"), "{se}");
    }
    let camera = tmp("i33-p11-camera.json");
    std::fs::write(
        &camera,
        r#"{"model": "pinhole", "width": 160, "height": 120, "fx": 100, "fy": 100, "cx": 80, "cy": 60, "distortion": "none"}"#,
    )
    .unwrap();
    let pose = tmp("i33-p11-pose.json");
    std::fs::write(
        &pose,
        r#"{"cMo": [[1,0,0,0],[0,1,0,0],[0,0,1,0.5],[0,0,0,1]]}"#,
    )
    .unwrap();
    let model = ds.join("model/scene.obj");
    let (_, se) = expect(
        &[
            "track",
            "--images",
            s(&cam0),
            "--camera",
            s(&camera),
            "--model",
            s(&model),
            "--start-pose",
            s(&pose),
            "--latency",
            "-1",
            "--out",
            s(&out),
        ],
        2,
    );
    // Refused before its value is looked at: a vision-only run has no trigger to wait from.
    assert_eq!(
        se.lines().last().unwrap(),
        "Error: --latency delays the correspondences after their IMU trigger: a vision-only run has no trigger to wait from"
    );
    assert!(!out.exists());
    let cache = tmp("i33-p11-cache");
    let (_, se) = expect(
        &[
            "eval",
            "--out",
            s(&out),
            "--cache",
            s(&cache),
            "--duration",
            "NaN",
        ],
        2,
    );
    assert!(se.contains("for '--duration <DURATION>'"), "{se}");
    for d in ["0.2", "0.3"] {
        let (_, se) = expect(
            &[
                "eval",
                "--out",
                s(&out),
                "--cache",
                s(&cache),
                "--duration",
                d,
            ],
            2,
        );
        assert_eq!(
            se,
            format!(
                "Error: --duration must be a number of seconds longer than the core's 0.30 s initialisation, got {d}\n"
            )
        );
    }
    assert!(
        !cache.exists() && !out.exists(),
        "nothing made before the refusal"
    );
}

/// Issue 33, point 11: `locate` where the model is not in the image said "0 RANSAC inliers (0
/// iterations)" of a search that ran, and exited 0 for "no pose found". It says what the
/// search did and exits 3, as a `track` that never started does.
#[test]
fn i33_p11_locate_without_a_pose_says_why_and_exits_3() {
    let ds = dataset();
    let cam0 = ds.join("mav0/cam0");
    let (calib, model) = (cam0.join("sensor.yaml"), ds.join("model/scene.obj"));
    let cache = tmp("i33-p11-locate-cache");
    // Texture without the model: a fixed pseudo-random pattern; and a flat image.
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let noise = image::GrayImage::from_fn(160, 120, |x, y| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        image::Luma([if (x / 4 + y / 4) % 2 == 0 {
            (state >> 56) as u8
        } else {
            128
        }])
    });
    let flat = image::GrayImage::from_pixel(160, 120, image::Luma([90]));
    for (name, img) in [("noise", noise), ("flat", flat)] {
        let path = tmp(&format!("i33-p11-{name}.png"));
        img.save(&path).unwrap();
        let out = tmp(&format!("i33-p11-locate-{name}"));
        let (so, _) = expect(
            &[
                "locate",
                "--image",
                s(&path),
                "--calib",
                s(&calib),
                "--model",
                s(&model),
                "--cache",
                s(&cache),
                "--out",
                s(&out),
            ],
            3,
        );
        assert!(
            so.contains("pose         none found") || so.contains("pose         not accepted"),
            "{name}: {so}"
        );
        assert!(!so.contains("(0 iterations)"), "{name}: {so}");
        if name == "flat" {
            assert!(so.contains("0 matches: too few for RANSAC"), "{so}");
        }
    }
}

/// Issue 33, point 11: `frames` with intrinsics that do not fit decoded every frame and
/// printed its report before failing; a camera for another frame size exited 1 where `track`
/// exits 2; a bad focal length was printed as a debug dump. The first frame is checked
/// first, both are usage errors, and the wrong value is named.
#[test]
fn i33_p11_frames_checks_the_camera_first_and_names_the_value() {
    let ds = dataset();
    let cam0 = ds.join("mav0/cam0");
    let (so, se) = expect(
        &[
            "frames",
            "--images",
            s(&cam0),
            "--intrinsics",
            "600,600,700,240",
        ],
        2,
    );
    assert_eq!(so, "", "no report before the refusal");
    assert_eq!(
        se,
        "Error: --intrinsics: invalid intrinsics: principal point (700, 240) outside the 160x120 image\n"
    );
    let (_, se) = expect(
        &[
            "frames",
            "--images",
            s(&cam0),
            "--intrinsics",
            "0,600,80,60",
        ],
        2,
    );
    assert!(
        se.contains("invalid intrinsics: the focal length fx must be positive [px], got 0"),
        "{se}"
    );
    assert!(!se.contains("Pinhole {"), "{se}");
    let camera = tmp("i33-p11-frames-camera.json");
    std::fs::write(
        &camera,
        r#"{"model": "pinhole", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240, "distortion": "none"}"#,
    )
    .unwrap();
    let (so, se) = expect(&["frames", "--images", s(&cam0), "--camera", s(&camera)], 2);
    assert_eq!(so, "");
    assert!(
        se.contains("the calibration is for 640x480 images, the frames are 160x120"),
        "{se}"
    );
}

/// Issue 33, point 2: a vision-only `trajectory.tum` alternated the prediction and the
/// estimate, 1 µs apart (jumps of 5.4 mm median, 62 mm max; a path length of 21.4 m where the
/// estimates alone make 14.8 m). It holds the estimates alone: one row per frame, a frame
/// period apart.
#[test]
fn i33_p02_a_vision_only_trajectory_holds_the_estimates_alone() {
    let no_imu = without_imu("i33-p02-no-imu");
    let out = tmp("i33-p02");
    expect(&track_args(&no_imu, &out, &["--overlay-every", "0"]), 0);
    let tum = std::fs::read_to_string(out.join("trajectory.tum")).unwrap();
    let stamps: Vec<f64> = tum
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| l.split_whitespace().next().unwrap().parse().unwrap())
        .collect();
    let frames = summary(&out)["frames"].as_u64().unwrap() as usize;
    assert!(
        stamps.len() > frames / 2 && stamps.len() <= frames,
        "{} rows, {frames} frames",
        stamps.len()
    );
    let closest = stamps
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min);
    assert!(closest > 0.01, "rows {closest} s apart");
}

/// Issue 33, point 10: `selftest --imu-samples` failed from 11,000 samples up ("loop-back
/// board: Broken pipe", then "Operation timed out"): its synthetic gyro rate, `0.01 k`, left
/// the protocol's range there, the board refused every sample after, and its refusals filled
/// the line back while the host was still writing; the board's consequent error was reported
/// instead of the host's. The rate now stays in range, 30,000 samples pass, and the flag's
/// bound (what both ends keep to compare) is a usage error.
#[test]
fn i33_p10_selftest_streams_many_samples() {
    let (so, _) = expect(&["selftest", "--imu-samples", "30000"], 0);
    assert!(so.contains("30000 IMU samples at"), "{so}");
    for n in ["0", "100001"] {
        let (_, se) = expect(&["selftest", "--imu-samples", n], 2);
        assert!(se.contains("for '--imu-samples <IMU_SAMPLES>'"), "{se}");
    }
}

/// Issue 33, point 4: a vision-only run over a serial link ended 0.09 s after the board was
/// killed ("write failed: Broken pipe", `outages: []`): only runs with an IMU reconnect. A
/// vision-only run is refused the links it could lose (serial, TCP) up front, with the reason.
#[test]
fn i33_p04_a_vision_only_run_is_refused_a_link_it_cannot_recover() {
    let no_imu = without_imu("i33-p04-no-imu");
    let out = tmp("i33-p04");
    for (link, name) in [
        ("serial:/dev/ttyACM0", "serial /dev/ttyACM0 at"),
        ("tcp:127.0.0.1:9", "tcp 127.0.0.1:9"),
    ] {
        let (_, se) = expect(&track_args(&no_imu, &out, &["--link", link]), 2);
        assert!(se.contains(&format!("Error: --link {name}")), "{se}");
        assert!(
            se.contains("a vision-only run does not reconnect to a core it loses"),
            "{se}"
        );
        assert!(!out.exists());
    }
}

/// Issue 34: the in-process core (`--link inproc`: the simulated board's device loop called
/// directly, no pty and no thread) tracks the tiny desktop-fast dataset to the same trajectory,
/// byte for byte, as the same board on its pty; with the IMU and vision-only.
#[test]
fn i34_the_in_process_core_tracks_as_the_board_on_a_pty() {
    let no_imu = without_imu("i34-no-imu");
    for (name, ds) in [("imu", dataset()), ("vision", no_imu)] {
        let mut runs = Vec::new();
        for link in ["sim", "inproc"] {
            let out = tmp(&format!("i34-{name}-{link}"));
            let (stdout, _) = expect(
                &track_args(&ds, &out, &["--link", link, "--overlay-every", "0"]),
                0,
            );
            assert!(stdout.contains(link), "{link}: {stdout}");
            runs.push(std::fs::read(out.join("trajectory.tum")).unwrap());
        }
        assert!(runs[0].len() > 100, "{name}: {} bytes", runs[0].len());
        assert!(runs[0] == runs[1], "{name}: the trajectories differ");
    }
}

/// Issue 35: bad input in a live run (`--pacing real-time`) is named, and what was tracked
/// before it is written: a frame of another size, and a video cut off mid-run (a pipe whose
/// writer died). A dataset whose stamps jump backwards is refused when it is opened (a live
/// frame that does is refused by the tracker, which goes on: the tracker's API tests).
#[test]
fn i35_live_bad_input_is_named_and_what_was_tracked_is_written() {
    use host_vision::camera::CameraPose;
    let live = |name: &str, input: &[&str], problem: &str| {
        let out = tmp(&format!("{name}-out"));
        let mut args = vec!["track", "--pacing", "real-time", "--overlay-every", "0"];
        args.extend_from_slice(input);
        args.extend_from_slice(&["--out", s(&out)]);
        let (_, se) = expect(&args, 1);
        assert!(se.contains(problem), "{name}: {se}");
        let sum = summary(&out);
        assert_eq!(sum["stopped_early"], true, "{name}");
        assert!(sum["error"].as_str().unwrap().contains(problem), "{name}");
        let analysed = sum["frames"].as_u64().unwrap();
        assert!(
            analysed >= 5,
            "{name}: {analysed} frames before the bad one"
        );
        assert!(out.join("trajectory.tum").exists(), "{name}");
        assert_eq!(sum["latency"]["live"], true);
    };
    // Frame 20's stamp before frame 19's.
    let back = without_imu("i35-backwards");
    let csv = back.join("mav0/cam0/data.csv");
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let stamp = |l: &str| l.split(',').next().unwrap().parse::<u64>().unwrap();
    let earlier = stamp(&lines[19]) - 1;
    let (_, name) = lines[21].split_once(',').unwrap();
    lines[21] = format!("{earlier},{name}");
    std::fs::write(&csv, lines.join("\n") + "\n").unwrap();
    // A dataset's stamps are all checked when it is opened: refused before anything runs.
    let out = tmp("i35-backwards-out");
    let (_, se) = expect(
        &[
            "track",
            "--pacing",
            "real-time",
            "--dataset",
            s(&back),
            "--out",
            s(&out),
        ],
        1,
    );
    assert!(se.contains("data.csv:22: time stamp"), "{se}");
    assert!(se.contains("not increasing"), "{se}");
    assert!(!out.exists());
    // Frame 20 of another size.
    let size = without_imu("i35-size");
    let (_, file) = lines[21].split_once(',').unwrap();
    let png = size.join("mav0/cam0/data").join(file.trim());
    image::GrayImage::new(80, 60).save(&png).unwrap();
    live(
        "i35-size",
        &["--dataset", s(&size)],
        "is 80x60 pixels, the first frame was 160x120",
    );
    // The frames as a video, cut off in the middle.
    let ds = dataset();
    let cam0 = ds.join("mav0/cam0");
    let whole = tmp("i35-whole.mkv");
    let ffmpeg = std::process::Command::new("ffmpeg")
        .args([
            "-v",
            "error",
            "-y",
            "-framerate",
            "20",
            "-pattern_type",
            "glob",
            "-i",
        ])
        .arg(format!("{}/data/*.png", cam0.display()))
        .args(["-c:v", "ffv1"])
        .arg(&whole)
        .status()
        .unwrap();
    assert!(ffmpeg.success());
    let bytes = std::fs::read(&whole).unwrap();
    let cut = tmp("i35-cut.mkv");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let d = frames::euroc::Dataset::open(&ds).unwrap();
    let (s_w, q_ws) = d.groundtruth_at(d.frames[0].stamp).unwrap();
    let (c_w, q_cw) = d.hand_eye.camera_pose(&s_w, &q_ws);
    let pose = tmp("i35-pose.json");
    std::fs::write(
        &pose,
        host_vision::start_pose::start_pose_json(&CameraPose { q_cw, c_w }),
    )
    .unwrap();
    live(
        "i35-cut",
        &[
            "--video",
            s(&cut),
            "--calib",
            s(&cam0.join("sensor.yaml")),
            "--model",
            s(&ds.join("model/scene.obj")),
            "--start-pose",
            s(&pose),
        ],
        "the stream ended abnormally after",
    );
}

/// Issue 36: `--imu-on-core` replays the tiny desktop-fast dataset with the core sampling its
/// own IMU: the readings through a simulated ICM-42688-P and the board's sample path, the
/// frames paired with the core's triggers. Its trajectory is the host-driven replay's of the
/// samples the core reported (`core_imu.csv`), byte for byte; the core's time stamps are the
/// dataset's; and what the mode cannot do is refused by name.
#[test]
fn i36_the_core_sampling_its_own_imu_tracks_as_the_host_driven_replay_of_its_samples() {
    let ds = dataset();
    let out = tmp("i36-core");
    let (stdout, _) = expect(
        &track_args(
            &ds,
            &out,
            &["--link", "inproc", "--imu-on-core", "--overlay-every", "0"],
        ),
        0,
    );
    assert!(stdout.contains("core_imu.csv"), "{stdout}");
    let sum = summary(&out);
    assert_eq!(sum["stopped_early"], false);
    // The samples the core took: every one of the dataset's, at its time stamp.
    let stamps = |p: &Path| -> Vec<u64> {
        std::fs::read_to_string(p)
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(|l| l.split(',').next().unwrap().parse().unwrap())
            .collect()
    };
    let taken = stamps(&out.join("core_imu.csv"));
    let truth = stamps(&ds.join("mav0/imu0/data.csv"));
    assert_eq!(taken, truth, "the core's stamps against the dataset's");
    // The host-driven replay of those samples: the same trajectory, byte for byte.
    let replay = tmp("i36-replay-data");
    copy_dir(&ds, &replay, "imu0");
    std::fs::create_dir_all(replay.join("mav0/imu0")).unwrap();
    std::fs::copy(
        ds.join("mav0/imu0/sensor.yaml"),
        replay.join("mav0/imu0/sensor.yaml"),
    )
    .unwrap();
    std::fs::copy(out.join("core_imu.csv"), replay.join("mav0/imu0/data.csv")).unwrap();
    let host = tmp("i36-host");
    expect(
        &track_args(
            &replay,
            &host,
            &["--link", "inproc", "--overlay-every", "0"],
        ),
        0,
    );
    let core_run = std::fs::read(out.join("trajectory.tum")).unwrap();
    assert!(core_run.len() > 100, "{} bytes", core_run.len());
    assert!(
        core_run == std::fs::read(host.join("trajectory.tum")).unwrap(),
        "the core-sampled and host-driven trajectories differ"
    );
    // Refused by name: a board that is not the in-process one, the vision-only model.
    for (more, problem) in [
        (
            vec!["--link", "sim", "--imu-on-core"],
            "--imu-on-core: the dataset's IMU is replayed through a simulated ICM-42688-P on the in-process board: use --link inproc",
        ),
        (
            vec!["--link", "inproc", "--imu-on-core", "--filter", "vision"],
            "the core's own IMU is for the inertial models",
        ),
    ] {
        let bad = tmp("i36-bad");
        let (_, se) = expect(&track_args(&ds, &bad, &more), 2);
        assert!(se.contains(problem), "{more:?}: {se}");
    }
}

/// Issue 56: `synth --object` names the flag and the file when the mesh cannot be read, and
/// writes nothing; `--lit` and `--ideal` (no lighting changes) are refused together.
#[test]
fn i56_synth_object_and_lit_are_checked_before_anything_is_written() {
    let out = tmp("i56-object");
    let missing = tmp("i56-no-such-mesh.obj");
    let (_, se) = expect(
        &[
            "synth",
            "--scenario",
            "desktop-fast",
            "--object",
            s(&missing),
            "--out",
            s(&out),
        ],
        1,
    );
    assert!(
        se.contains("--object") && se.contains("i56-no-such-mesh.obj"),
        "{se}"
    );
    assert!(!out.exists(), "nothing written");
    let (_, se) = expect(
        &[
            "synth",
            "--scenario",
            "desktop-fast",
            "--lit",
            "--ideal",
            "--out",
            s(&out),
        ],
        2,
    );
    assert!(se.contains("--lit") && se.contains("--ideal"), "{se}");
    assert!(!out.exists(), "nothing written");
}
