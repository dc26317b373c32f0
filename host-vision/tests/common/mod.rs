//! What the command-line tests share: `host-vision` run as a process, and the tiny dataset
//! every `track` run of theirs reads.

#![allow(dead_code)]

use std::io::{BufRead as _, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

pub const HV: &str = env!("CARGO_BIN_EXE_host-vision");

/// A fresh path under the test binary's own folder of the target's scratch space.
pub fn tmp(name: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(env!("CARGO_CRATE_NAME"))
        .join(name);
    let _ = std::fs::remove_dir_all(&p);
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    p
}

pub fn hv(args: &[&str]) -> Output {
    Command::new(HV)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap_or_else(|e| panic!("start {HV}: {e}"))
}

pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Runs `args`, checks the exit code, returns (stdout, stderr).
pub fn expect(args: &[&str], code: i32) -> (String, String) {
    let out = hv(args);
    let (so, se) = (text(&out.stdout), text(&out.stderr));
    assert_eq!(
        out.status.code(),
        Some(code),
        "host-vision {}\nstdout:\n{so}\nstderr:\n{se}",
        args.join(" ")
    );
    (so, se)
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The tiny dataset (1.5 s of desktop-fast at 160×120, made by `host-vision synth`), made once
/// per test process by the command itself, in the binary's own folder.
pub fn dataset() -> PathBuf {
    static DONE: Mutex<bool> = Mutex::new(false);
    let mut done = DONE.lock().unwrap_or_else(|e| e.into_inner());
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("{}-dataset", env!("CARGO_CRATE_NAME")));
    if !*done {
        expect(
            &[
                "synth",
                "--scenario",
                "desktop-fast",
                "--duration",
                "1.5",
                "--resolution",
                "160x120",
                "--out",
                s(&dir),
                "--overwrite",
            ],
            0,
        );
        *done = true;
    }
    dir
}

/// `track` on the tiny dataset into `out`, with more arguments.
pub fn track_args<'a>(ds: &'a Path, out: &'a Path, more: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec!["track", "--dataset", s(ds), "--out", s(out)];
    a.extend_from_slice(more);
    a
}

pub fn copy_dir(from: &Path, to: &Path, skip: &str) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_name() == skip {
            continue;
        }
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target, skip);
        } else {
            std::fs::copy(e.path(), &target).unwrap();
        }
    }
}

/// The tiny dataset without its IMU (vision-only), copied to `name`.
pub fn without_imu(name: &str) -> PathBuf {
    let no_imu = tmp(name);
    copy_dir(&dataset(), &no_imu, "imu0");
    no_imu
}

pub fn count(haystack: &str, needle: &str) -> usize {
    haystack.matches(needle).count()
}

/// The summary a run wrote.
pub fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

/// `frames.csv` as rows of named fields.
pub fn frame_rows(out: &Path) -> Vec<std::collections::BTreeMap<String, String>> {
    let text = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines
        .map(|l| {
            header
                .iter()
                .cloned()
                .zip(l.split(',').map(String::from))
                .collect()
        })
        .collect()
}

/// Waits for `child` (a guard against a hang, not a speed requirement).
pub fn wait(child: &mut Child, what: &str) -> std::process::ExitStatus {
    let deadline = Instant::now() + Duration::from_secs(300);
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        assert!(Instant::now() < deadline, "{what}: no exit");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Runs `args` and sends it `signal` (`INT`, `TERM`, …) `after` it printed a line containing
/// `when` on stdout; returns its exit code, what it printed on stdout and on stderr.
pub fn signal_when(
    args: &[&str],
    when: &str,
    signal: &str,
    after: Duration,
) -> (Option<i32>, String, String) {
    let mut child = Command::new(HV)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let err = std::thread::spawn(move || std::io::read_to_string(stderr).unwrap_or_default());
    let mut printed = String::new();
    let mut sent = false;
    for line in BufReader::new(child.stdout.take().unwrap()).lines() {
        let line = line.unwrap();
        if !sent && line.contains(when) {
            std::thread::sleep(after);
            let kill = Command::new("kill")
                .args([&format!("-{signal}"), &child.id().to_string()])
                .status()
                .unwrap();
            assert!(kill.success());
            sent = true;
        }
        printed += &line;
        printed.push('\n');
    }
    let status = wait(&mut child, &args.join(" "));
    assert!(sent, "`{when}` never printed:\n{printed}");
    (status.code(), printed, err.join().unwrap())
}
