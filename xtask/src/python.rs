//! The Python module's part of `cargo xtask test`: a virtual environment of its own
//! (`target/python-venv`) with the packages of `python/requirements-test.txt` from the package
//! registry; the wheel built with maturin in the dev profile (the test profile's settings: the
//! crates the test build compiled are reused), installed there, and the module's tests run with pytest against the Rust programs the test
//! build made (the `track_video` example, `host-vision`).

use std::path::PathBuf;
use std::process::Command;

use crate::steps::Steps;
use crate::{is_debian, is_root, succeeds, target_dir, workspace_root};

/// The virtual environment's folder.
fn venv_dir() -> PathBuf {
    target_dir().join("python-venv")
}

/// The interpreter to make the environment with: `PYTHON`, else `python3`.
fn python3() -> String {
    std::env::var("PYTHON").unwrap_or_else(|_| "python3".into())
}

/// Makes the virtual environment where it is missing (on Debian as root, with `python3-venv`
/// installed first where `venv` is missing), and installs or updates its packages.
fn venv(steps: &mut Steps) -> Result<PathBuf, String> {
    let dir = venv_dir();
    let python = dir.join("bin/python");
    if !python.exists() {
        let py = python3();
        if !succeeds(&py, &["-c", "import venv, ensurepip"]) {
            if is_debian() && is_root() {
                let mut install = Command::new("apt-get");
                install
                    .args([
                        "install",
                        "-y",
                        "-q",
                        "--no-install-recommends",
                        "python3-venv",
                    ])
                    .env("DEBIAN_FRONTEND", "noninteractive");
                steps.run("python3-venv", install)?;
            } else {
                return Err(format!(
                    "{py} cannot make a virtual environment (`{py} -m venv`): install Python 3.9 \
                     or later with its venv module (Debian: `apt-get install python3-venv`), or \
                     name another interpreter in PYTHON"
                ));
            }
        }
        let mut make = Command::new(&py);
        make.args(["-m", "venv"]).arg(&dir);
        steps.run("python environment", make)?;
    }
    let mut pip = Command::new(&python);
    pip.args([
        "-m",
        "pip",
        "install",
        "--quiet",
        "--disable-pip-version-check",
        "-r",
    ])
    .arg(workspace_root().join("python/requirements-test.txt"));
    steps.run("python packages", pip)?;
    Ok(python)
}

/// The executables of non-test artifacts in cargo's JSON messages, by `kind name` (`bin
/// host-vision`, `example track_video`).
fn executable(messages: &str, kind: &str, name: &str) -> Option<PathBuf> {
    messages
        .lines()
        .filter(|l| l.starts_with('{'))
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|m| m["reason"] == "compiler-artifact" && m["profile"]["test"] == false)
        .filter(|m| m["target"]["kind"][0] == kind && m["target"]["name"] == name)
        .find_map(|m| m["executable"].as_str().map(PathBuf::from))
}

/// Builds and installs the wheel, then runs the module's tests. `messages` are the test
/// build's (for the Rust programs the tests compare with).
pub fn test(steps: &mut Steps, messages: &str) -> Result<(), String> {
    let python = venv(steps)?;
    let wheels = target_dir().join("wheels");
    // One wheel there: the one built now.
    let _ = std::fs::remove_dir_all(&wheels);
    let mut build = Command::new(python.with_file_name("maturin"));
    build
        .current_dir(workspace_root())
        .args([
            "build",
            "--quiet",
            "-m",
            "python/Cargo.toml",
            "--profile",
            "dev",
        ])
        .arg("--interpreter")
        .arg(&python)
        .arg("--out")
        .arg(&wheels);
    steps.run("python wheel", build)?;
    let wheel = std::fs::read_dir(&wheels)
        .map_err(|e| format!("{}: {e}", wheels.display()))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .find(|p| p.extension().is_some_and(|x| x == "whl"))
        .ok_or(format!("maturin left no wheel in {}", wheels.display()))?;
    let size = std::fs::metadata(&wheel).map_or(0, |m| m.len());
    println!(
        "xtask: the wheel {} is {:.1} MB",
        wheel.file_name().unwrap_or_default().to_string_lossy(),
        size as f64 / 1e6
    );
    let mut install = Command::new(&python);
    install
        .args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "--disable-pip-version-check",
        ])
        .args(["--force-reinstall", "--no-deps"])
        .arg(&wheel);
    steps.run("python install", install)?;

    let mut pytest = Command::new(&python);
    pytest
        .current_dir(workspace_root())
        .args([
            "-m",
            "pytest",
            "python/tests",
            "-q",
            "-p",
            "no:cacheprovider",
        ])
        .env("WGPU_BACKEND", "vulkan")
        .env("NODEVICE_SELECT", "1")
        // The Rust locate tests' cache (CARGO_TARGET_TMPDIR): the cube's database is there.
        .env(
            "VITRACKER_LOCATE_CACHE",
            target_dir().join("tmp/locate-cache"),
        );
    for (variable, kind, name) in [
        ("VITRACKER_TRACK_VIDEO", "example", "track_video"),
        ("VITRACKER_HOST_VISION", "bin", "host-vision"),
    ] {
        let exe = executable(messages, kind, name)
            .ok_or(format!("the test build made no {kind} {name}"))?;
        pytest.env(variable, exe);
    }
    steps.run("python tests", pytest)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn examples_and_programs_are_found_in_cargos_messages() {
        let messages = r#"{"reason":"compiler-artifact","profile":{"test":false},"target":{"kind":["example"],"name":"track_video"},"executable":"/t/debug/examples/track_video"}
{"reason":"compiler-artifact","profile":{"test":true},"target":{"kind":["bin"],"name":"host-vision"},"executable":"/t/debug/deps/host_vision-1"}
{"reason":"compiler-artifact","profile":{"test":false},"target":{"kind":["bin"],"name":"host-vision"},"executable":"/t/debug/host-vision"}"#;
        assert_eq!(
            executable(messages, "example", "track_video"),
            Some(PathBuf::from("/t/debug/examples/track_video"))
        );
        assert_eq!(
            executable(messages, "bin", "host-vision"),
            Some(PathBuf::from("/t/debug/host-vision"))
        );
        assert_eq!(executable(messages, "bin", "firmware-sim"), None);
    }
}
