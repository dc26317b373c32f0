//! The steps of `cargo xtask test` and their times (issue 34: the suite must stay within its
//! budget, and the next slow test must be visible): every command is run through [`Steps`],
//! which prints it, times it, and at the end prints all times, the longest first.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// The steps run so far: a name and its wall-clock time [s].
#[derive(Default)]
pub struct Steps {
    done: Vec<(String, f64)>,
}

impl Steps {
    /// Runs `cmd` as step `name`, echoing it; fails with its exit status.
    pub fn run(&mut self, name: &str, mut cmd: Command) -> Result<(), String> {
        let shown = shown(&cmd);
        println!("\n==> {name}: {shown}");
        let start = Instant::now();
        let status = cmd
            .status()
            .map_err(|e| format!("cannot start `{shown}`: {e}"))?;
        let seconds = start.elapsed().as_secs_f64();
        println!("<== {name}: {status} after {seconds:.1} s");
        self.done.push((name.to_owned(), seconds));
        if status.success() {
            Ok(())
        } else {
            Err(format!("{name}: `{shown}` failed ({status})"))
        }
    }

    /// Runs `cmd` as step `name` and returns its standard output (standard error passes
    /// through); fails with its exit status.
    pub fn output(&mut self, name: &str, mut cmd: Command) -> Result<String, String> {
        let shown = shown(&cmd);
        println!("\n==> {name}: {shown}");
        let start = Instant::now();
        let out = cmd
            .stderr(std::process::Stdio::inherit())
            .output()
            .map_err(|e| format!("cannot start `{shown}`: {e}"))?;
        let seconds = start.elapsed().as_secs_f64();
        println!("<== {name}: {} after {seconds:.1} s", out.status);
        self.done.push((name.to_owned(), seconds));
        if out.status.success() {
            Ok(String::from_utf8_lossy(&out.stdout).into_owned())
        } else {
            Err(format!("{name}: `{shown}` failed ({})", out.status))
        }
    }

    /// The times of all steps, the longest first, and their sum.
    pub fn report(&self) -> String {
        let mut by_time: Vec<&(String, f64)> = self.done.iter().collect();
        by_time.sort_by(|a, b| b.1.total_cmp(&a.1));
        let width = by_time.iter().map(|(n, _)| n.len()).max().unwrap_or(0);
        let mut text = String::from("xtask: time per step, the longest first:\n");
        for (name, seconds) in by_time {
            text.push_str(&format!("  {name:width$}  {seconds:7.1} s\n"));
        }
        let total: f64 = self.done.iter().map(|(_, s)| s).sum();
        text.push_str(&format!("  {:width$}  {total:7.1} s", "sum of the steps"));
        text
    }
}

/// A command as a shell would show it.
fn shown(cmd: &Command) -> String {
    format!(
        "{} {}",
        cmd.get_program().to_string_lossy(),
        cmd.get_args()
            .map(|a| a.to_string_lossy().into_owned())
            .collect::<Vec<_>>()
            .join(" ")
    )
}

/// A test executable cargo built: its package's folder (where cargo runs it), and a name for
/// its step (`package kind target`).
#[derive(Debug, Clone, PartialEq)]
pub struct TestBinary {
    /// The package's folder.
    pub dir: PathBuf,
    /// `host-vision test visp_cube`, `camera lib camera`, ...
    pub name: String,
    /// The package's name.
    pub package: String,
    /// The executable.
    pub path: PathBuf,
}

/// The test executables in cargo's JSON messages (`cargo test --no-run --message-format=json`):
/// the compiler artifacts built with the test profile that have an executable.
pub fn test_binaries(messages: &str) -> Result<Vec<TestBinary>, String> {
    let mut found = Vec::new();
    for line in messages.lines().filter(|l| l.starts_with('{')) {
        let m: serde_json::Value =
            serde_json::from_str(line).map_err(|e| format!("cargo's message {line}: {e}"))?;
        if m["reason"] != "compiler-artifact" || m["profile"]["test"] != true {
            continue;
        }
        let (Some(path), Some(manifest)) = (m["executable"].as_str(), m["manifest_path"].as_str())
        else {
            continue;
        };
        let dir = Path::new(manifest)
            .parent()
            .ok_or(format!("cargo's manifest path {manifest} has no folder"))?;
        let package = m["package_id"]
            .as_str()
            .and_then(package_name)
            .unwrap_or_default()
            .to_owned();
        let kind = m["target"]["kind"][0].as_str().unwrap_or("?");
        let target = m["target"]["name"].as_str().unwrap_or("?");
        found.push(TestBinary {
            dir: dir.to_owned(),
            name: format!("{package} {kind} {target}"),
            package,
            path: PathBuf::from(path),
        });
    }
    Ok(found)
}

/// The package's name in a package id: `path+file:///w/host/camera#0.1.0` (the folder, when the
/// name equals it), `path+file:///w/host-vision#name@0.1.0`, or the older `name 0.1.0 (…)`.
fn package_name(id: &str) -> Option<&str> {
    if let Some((url, fragment)) = id.split_once('#') {
        return Some(match fragment.split_once('@') {
            Some((name, _)) => name,
            None => url.rsplit('/').next()?,
        });
    }
    id.split_whitespace().next()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn test_executables_are_found_in_cargos_messages() {
        let messages = concat!(
            r#"{"reason":"compiler-artifact","package_id":"path+file:///w/host/camera#0.1.0","manifest_path":"/w/host/camera/Cargo.toml","target":{"kind":["lib"],"name":"camera"},"profile":{"test":true},"executable":"/w/target/debug/deps/camera-1"}"#,
            "\n",
            r#"{"reason":"compiler-artifact","package_id":"path+file:///w/host/camera#0.1.0","manifest_path":"/w/host/camera/Cargo.toml","target":{"kind":["lib"],"name":"camera"},"profile":{"test":false},"executable":null}"#,
            "\n",
            r#"{"reason":"compiler-artifact","package_id":"path+file:///w/hv#host-vision@0.1.0","manifest_path":"/w/hv/Cargo.toml","target":{"kind":["test"],"name":"visp_cube"},"profile":{"test":true},"executable":"/w/target/debug/deps/visp_cube-2"}"#,
            "\n",
            r#"{"reason":"build-finished","success":true}"#,
            "\n"
        );
        let found = test_binaries(messages).unwrap();
        assert_eq!(found.len(), 2);
        assert_eq!(found[0].name, "camera lib camera");
        assert_eq!(found[0].dir, Path::new("/w/host/camera"));
        assert_eq!(found[1].name, "host-vision test visp_cube");
        assert_eq!(found[1].package, "host-vision");
        assert_eq!(found[1].path, Path::new("/w/target/debug/deps/visp_cube-2"));
        assert_eq!(
            package_name("host-vision 0.1.0 (path+file:///w)"),
            Some("host-vision")
        );
    }

    #[test]
    fn the_report_lists_the_longest_first_with_the_sum() {
        let s = Steps {
            done: vec![("short".into(), 1.0), ("long".into(), 30.0)],
        };
        let r = s.report();
        assert!(r.find("long").unwrap() < r.find("short").unwrap(), "{r}");
        assert!(r.ends_with("31.0 s"), "{r}");
    }
}
