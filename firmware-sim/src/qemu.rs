//! Runs the firmware image on QEMU's Cortex-M4F board (`mps2-an386`) and connects to its
//! UART over TCP, so the host talks to it exactly as to hardware on a serial line.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
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
    /// QEMU's machine protocol (QMP) failed or refused a command.
    #[error("QMP: {0}")]
    Qmp(String),
    /// The image lacks a symbol the measurement needs, or is not an ELF32 file.
    #[error("firmware image: {0}")]
    Image(String),
}

/// What the device image uses of its RAM, read from a running board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RamUse {
    /// `.data` + `.bss` + `.uninit`: from the start of RAM to `__sheap`.
    pub static_bytes: u32,
    /// Deepest stack use since boot: from the lowest word that no longer holds the paint
    /// pattern (`firmware/src/stack.rs`) to the top of the stack.
    pub stack_high_water: u32,
}

/// A running QEMU board; killed when dropped.
#[derive(Debug)]
pub struct QemuBoard {
    child: Child,
    /// QEMU's machine protocol, for reading memory (`ram_use`).
    qmp_port: u16,
}

impl QemuBoard {
    /// Starts `image` on `mps2-an386` with its UART on a local TCP port and connects to it.
    /// `-icount shift=0` makes virtual time count instructions (1 ns each).
    ///
    /// The ports are picked free and then handed to QEMU, so another process can take one in
    /// between (CI runs suites side by side): QEMU then exits with "Address already in use",
    /// and the start is tried again on fresh ports, a few times.
    pub fn start(image: &Path, connect_within: Duration) -> Result<(QemuBoard, Duplex), QemuError> {
        if !image.is_file() {
            return Err(QemuError::MissingImage(image.to_owned()));
        }
        const TRIES: usize = 5;
        let mut tries = 0;
        loop {
            tries += 1;
            match Self::start_once(image, connect_within) {
                Err(QemuError::Exited(why)) if tries < TRIES && why.contains("already in use") => {}
                other => return other,
            }
        }
    }

    fn start_once(
        image: &Path,
        connect_within: Duration,
    ) -> Result<(QemuBoard, Duplex), QemuError> {
        // Both listeners are held until QEMU is spawned, so the two ports differ.
        let bind = || TcpListener::bind("127.0.0.1:0").map_err(QemuError::Port);
        let port_of = |l: &TcpListener| l.local_addr().map(|a| a.port()).map_err(QemuError::Port);
        let (serial_l, qmp_l) = (bind()?, bind()?);
        let (port, qmp_port) = (port_of(&serial_l)?, port_of(&qmp_l)?);
        drop((serial_l, qmp_l));
        let qmp = format!("tcp:127.0.0.1:{qmp_port},server=on,wait=off");
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
            .args(["-qmp", &qmp])
            .args(["-serial", &serial, "-kernel"])
            .arg(image)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(QemuError::NotInstalled)?;
        let mut board = QemuBoard { child, qmp_port };
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

impl QemuBoard {
    /// Static RAM and stack high-water of `image` (the one running) so far, read from the
    /// board's memory: the free stack that the image painted at boot (`firmware::stack::paint`)
    /// is saved through QMP's `pmemsave` and searched for the deepest overwritten word, as
    /// `firmware::stack::high_water` does on the device.
    pub fn ram_use(&mut self, image: &Path) -> Result<RamUse, QemuError> {
        const PAINT: u32 = 0xDEAD_BEEF;
        const RAM: u32 = 0x2000_0000;
        let elf = std::fs::read(image).map_err(|e| QemuError::Image(e.to_string()))?;
        let bottom = elf32_symbol(&elf, "__sheap")?;
        let top = elf32_symbol(&elf, "_stack_start")?;
        let dump =
            std::env::temp_dir().join(format!("qemu-ram-{}-{}", std::process::id(), self.qmp_port));
        let stream = TcpStream::connect(("127.0.0.1", self.qmp_port))
            .map_err(|e| QemuError::Qmp(e.to_string()))?;
        stream
            .set_read_timeout(Some(Duration::from_secs(20)))
            .map_err(|e| QemuError::Qmp(e.to_string()))?;
        let mut lines = BufReader::new(
            stream
                .try_clone()
                .map_err(|e| QemuError::Qmp(e.to_string()))?,
        );
        let mut out = stream;
        let mut command = |cmd: String| -> Result<(), QemuError> {
            out.write_all(cmd.as_bytes())
                .map_err(|e| QemuError::Qmp(e.to_string()))?;
            // Skip the greeting and events; the command's own answer is `return` or `error`.
            loop {
                let mut line = String::new();
                if lines
                    .read_line(&mut line)
                    .map_err(|e| QemuError::Qmp(e.to_string()))?
                    == 0
                {
                    return Err(QemuError::Qmp("connection closed".into()));
                }
                if line.contains("\"return\"") {
                    return Ok(());
                }
                if line.contains("\"error\"") {
                    return Err(QemuError::Qmp(line.trim().to_owned()));
                }
            }
        };
        command("{\"execute\": \"qmp_capabilities\"}\n".into())?;
        command(format!(
            "{{\"execute\": \"pmemsave\", \"arguments\": {{\"val\": {bottom}, \"size\": {}, \"filename\": {:?}}}}}\n",
            top - bottom,
            dump.display().to_string()
        ))?;
        let ram =
            std::fs::read(&dump).map_err(|e| QemuError::Qmp(format!("{}: {e}", dump.display())));
        let _ = std::fs::remove_file(&dump);
        let ram = ram?;
        let painted = ram
            .chunks_exact(4)
            .take_while(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]) == PAINT)
            .count() as u32;
        Ok(RamUse {
            static_bytes: bottom - RAM,
            stack_high_water: top - bottom - 4 * painted,
        })
    }
}

/// The value of the symbol `name` in a little-endian ELF32 file.
fn elf32_symbol(d: &[u8], name: &str) -> Result<u32, QemuError> {
    let u16_at = |o: usize| {
        d.get(o..o + 2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]) as usize)
    };
    let u32_at = |o: usize| {
        d.get(o..o + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let find = || -> Option<u32> {
        if d.get(..5)? != b"\x7fELF\x01" {
            return None;
        }
        let (shoff, shentsize, shnum) = (u32_at(0x20)? as usize, u16_at(0x2e)?, u16_at(0x30)?);
        let header = |i: usize| shoff + i * shentsize;
        let symtab = (0..shnum).find(|&i| u32_at(header(i) + 4) == Some(2))?;
        let strtab = header(u32_at(header(symtab) + 24)? as usize);
        let (sym_off, sym_len) = (
            u32_at(header(symtab) + 16)? as usize,
            u32_at(header(symtab) + 20)? as usize,
        );
        let str_off = u32_at(strtab + 16)? as usize;
        (sym_off..sym_off + sym_len).step_by(16).find_map(|s| {
            let at = str_off + u32_at(s)? as usize;
            let end = at + d.get(at..)?.iter().position(|&b| b == 0)?;
            (&d[at..end] == name.as_bytes())
                .then(|| u32_at(s + 4))
                .flatten()
        })
    };
    find().ok_or_else(|| QemuError::Image(format!("no symbol {name}")))
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
