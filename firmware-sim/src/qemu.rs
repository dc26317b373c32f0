//! Runs the firmware image on QEMU's Cortex-M4F board (`mps2-an386`) and connects to its
//! UART over TCP, so the host talks to it exactly as to hardware on a serial line.

use std::io::Read;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::thread;
use std::time::{Duration, Instant};

use crate::transport::{self, Duplex, TransportError};

/// Why the board could not be started.
#[derive(Debug, thiserror::Error)]
pub enum QemuError {
    /// The firmware image does not exist.
    #[error("firmware image {0} not found (build it with `cargo xtask firmware`)")]
    MissingImage(PathBuf),
    /// QEMU is not installed.
    #[error("cannot start qemu-system-arm ({0}); install the Debian package qemu-system-arm")]
    NotInstalled(#[source] std::io::Error),
    /// No free local port.
    #[error("no free TCP port on 127.0.0.1: {0}")]
    Port(#[source] std::io::Error),
    /// QEMU exited before accepting the connection.
    #[error("qemu-system-arm exited early: {0}")]
    Exited(String),
    /// The connection could not be made in time.
    #[error("could not connect to QEMU's UART within {0:?}")]
    Timeout(Duration),
    /// The TCP link failed.
    #[error(transparent)]
    Transport(#[from] TransportError),
}

/// A running QEMU board; killed when dropped.
#[derive(Debug)]
pub struct QemuBoard {
    child: Child,
}

impl QemuBoard {
    /// Starts `image` on `mps2-an386` with its UART on a local TCP port and connects to it.
    /// `-icount shift=0` makes virtual time count instructions (1 ns each).
    pub fn start(image: &Path, connect_within: Duration) -> Result<(QemuBoard, Duplex), QemuError> {
        if !image.is_file() {
            return Err(QemuError::MissingImage(image.to_owned()));
        }
        let port = TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map_err(QemuError::Port)?
            .port();
        let serial = format!("tcp:127.0.0.1:{port},server=on,wait=on,nodelay=on");
        let child = Command::new("qemu-system-arm")
            .args([
                "-machine",
                "mps2-an386",
                "-cpu",
                "cortex-m4",
                "-nographic",
                "-monitor",
                "none",
            ])
            .args(["-semihosting-config", "enable=on,target=native"])
            .args(["-serial", &serial, "-kernel"])
            .arg(image)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(QemuError::NotInstalled)?;
        let mut board = QemuBoard { child };
        let start = Instant::now();
        loop {
            match transport::tcp_connect(("127.0.0.1", port)) {
                Ok(duplex) => return Ok((board, duplex)),
                Err(_) if start.elapsed() < connect_within => {
                    if let Ok(Some(status)) = board.child.try_wait() {
                        let mut err = String::new();
                        if let Some(mut e) = board.child.stderr.take() {
                            let _ = e.read_to_string(&mut err);
                        }
                        return Err(QemuError::Exited(format!("{status}: {}", err.trim())));
                    }
                    thread::sleep(Duration::from_millis(20));
                }
                Err(_) => return Err(QemuError::Timeout(connect_within)),
            }
        }
    }
}

impl Drop for QemuBoard {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The default location of a firmware binary built by `cargo xtask firmware`.
pub fn default_image(workspace: &Path, name: &str) -> PathBuf {
    workspace
        .join("firmware/target/thumbv7em-none-eabihf/release")
        .join(name)
}
