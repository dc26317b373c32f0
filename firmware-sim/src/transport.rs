//! Byte transports between host and core: a pty pair (a real serial line in one process), a
//! serial device, TCP, and stdio. Each yields a [`Duplex`]: a reader and a writer that can be
//! moved to different threads.

use std::io::{self, Read, Write};
use std::net::{TcpListener, TcpStream, ToSocketAddrs};
use std::time::Duration;

use serialport::{SerialPort, TTYPort};

/// How long a read waits before it reports `TimedOut`, so that callers can check deadlines
/// and shutdown flags.
pub const POLL_INTERVAL: Duration = Duration::from_millis(50);

/// Whether a read error only means "nothing arrived within [`POLL_INTERVAL`]" (or a signal
/// interrupted the wait): the caller checks its deadlines and reads again.
pub fn is_poll_timeout(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
    )
}

/// Whether an I/O error means the peer hung up (a socket closed with data unread resets the
/// connection; writing to a closed pipe breaks it): the session is over, not failed.
pub fn is_hang_up(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::ConnectionReset
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::BrokenPipe
    )
}

/// Errors opening a transport.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The pty pair could not be created.
    #[error("cannot open a pty pair: {0}")]
    Pty(#[source] serialport::Error),
    /// The serial device could not be opened.
    #[error(
        "cannot open serial device {path} at {baud} baud: {source}{}",
        busy_hint(source)
    )]
    Serial {
        /// Device path.
        path: String,
        /// Baud rate.
        baud: u32,
        /// Cause.
        #[source]
        source: serialport::Error,
    },
    /// Nothing took the connection: no board there, or one serving another host.
    #[error(
        "TCP connect to {addr}: {source}: is the board (firmware-sim --link tcp:{addr}) running, and free? It serves one host and exits, unless started with --forever"
    )]
    TcpRefused {
        /// Address.
        addr: String,
        /// Cause.
        #[source]
        source: io::Error,
    },
    /// A TCP connection failed.
    #[error("TCP {what} {addr}: {source}")]
    Tcp {
        /// `connect to` or `listen on`.
        what: &'static str,
        /// Address.
        addr: String,
        /// Cause.
        #[source]
        source: io::Error,
    },
}

/// Both directions of a byte link.
pub struct Duplex {
    /// Incoming bytes. Reads time out after [`POLL_INTERVAL`] where the transport supports it.
    pub reader: Box<dyn Read + Send>,
    /// Outgoing bytes.
    pub writer: Box<dyn Write + Send>,
    /// Human-readable description (device path, address).
    pub name: String,
}

impl std::fmt::Debug for Duplex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Duplex").field("name", &self.name).finish()
    }
}

fn tty_duplex(mut port: TTYPort, name: String) -> Result<Duplex, serialport::Error> {
    port.set_timeout(POLL_INTERVAL)?;
    let writer = port.try_clone_native()?;
    Ok(Duplex {
        reader: Box::new(PtyReader(port)),
        writer: Box::new(TtyWriter(writer)),
        name,
    })
}

/// `TTYPort` writes go straight to the kernel; its `flush` is `tcdrain`, which waits until the
/// peer has read everything and fails if the peer closes meanwhile. A framed writer only needs
/// the bytes handed to the kernel, so flushing is a no-op here.
struct TtyWriter(TTYPort);

impl Write for TtyWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.write(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// A tty read fails with a hang-up (`BrokenPipe` from poll, or `EIO`) once the other end is
/// closed; report that as the end of the stream, as a socket would.
struct PtyReader(TTYPort);

const EIO: i32 = 5;

impl Read for PtyReader {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self.0.read(buf) {
            Err(e) if e.kind() == io::ErrorKind::BrokenPipe || e.raw_os_error() == Some(EIO) => {
                Ok(0)
            }
            other => other,
        }
    }
}

/// Marks `ports` close-on-exec. serialport opens a pty pair without it, so a program the
/// process starts later (ffmpeg for a video, another test's) held both ends open, and the
/// board never saw its host hang up until that program ended (issue 54: "the simulated board
/// did not end its session").
fn close_on_exec(ports: &[&TTYPort]) -> Result<(), TransportError> {
    use nix::fcntl::{FcntlArg, FdFlag, fcntl};
    use std::os::fd::AsRawFd as _;
    for port in ports {
        fcntl(port.as_raw_fd(), FcntlArg::F_SETFD(FdFlag::FD_CLOEXEC))
            .map_err(|e| TransportError::Pty(io::Error::from(e).into()))?;
    }
    Ok(())
}

/// What a refused open of a serial device means when another process holds it: hosts open
/// the core's device exclusively, so that one host drives it at a time (protocol/PROTOCOL.md §8).
fn busy_hint(e: &serialport::Error) -> &'static str {
    let busy = matches!(
        e.kind,
        serialport::ErrorKind::Io(io::ErrorKind::ResourceBusy)
    ) || e.description.contains("busy")
        || e.description.contains("would block")
        || e.description.contains("exclusive");
    if busy {
        " (another host holds it: the core is driven by one host at a time)"
    } else {
        ""
    }
}

/// Opens a pty pair: `(host end, board end)`. Bytes cross the kernel's tty layer in raw mode,
/// exactly as over a USB serial adaptor.
pub fn pty_pair() -> Result<(Duplex, Duplex), TransportError> {
    let (master, slave) = TTYPort::pair().map_err(TransportError::Pty)?;
    close_on_exec(&[&master, &slave])?;
    let slave_name = slave.name().unwrap_or_else(|| "pty".into());
    let host =
        tty_duplex(master, format!("pty master of {slave_name}")).map_err(TransportError::Pty)?;
    let board = tty_duplex(slave, slave_name).map_err(TransportError::Pty)?;
    Ok((host, board))
}

/// Opens a pty for a host in another process, which opens the device by its path as a serial
/// line: `(board end, device path)`. The session ends when that host closes the device. A pty
/// whose device no process holds reads as hung up, so the board holds the device itself until
/// the host's first bytes arrive (the host has it open then), and lets go of it after that:
/// the host's close is then the end of the stream, and a second host finds no device.
pub fn pty_for_peer() -> Result<(Duplex, String), TransportError> {
    let (master, slave) = TTYPort::pair().map_err(TransportError::Pty)?;
    close_on_exec(&[&master, &slave])?;
    let path = slave.name().unwrap_or_else(|| "pty".into());
    let mut board = tty_duplex(master, path.clone()).map_err(TransportError::Pty)?;
    board.reader = Box::new(HoldUntilData {
        reader: board.reader,
        held: Some(slave),
    });
    Ok((board, path))
}

/// Keeps the pty's device open until the first bytes come through (see [`pty_for_peer`]).
struct HoldUntilData {
    reader: Box<dyn Read + Send>,
    held: Option<TTYPort>,
}

impl Read for HoldUntilData {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.reader.read(buf)?;
        if n > 0 {
            self.held = None;
        }
        Ok(n)
    }
}

/// Opens a serial device (hardware board, or a pty made by another program).
pub fn serial(path: &str, baud: u32) -> Result<Duplex, TransportError> {
    let err = |source| TransportError::Serial {
        path: path.to_string(),
        baud,
        source,
    };
    let port = serialport::new(path, baud)
        .timeout(POLL_INTERVAL)
        .open_native()
        .map_err(err)?;
    tty_duplex(port, path.to_string()).map_err(err)
}

fn tcp_duplex(
    stream: TcpStream,
    addr: String,
    what: &'static str,
) -> Result<Duplex, TransportError> {
    let err = |source| TransportError::Tcp {
        what,
        addr: addr.clone(),
        source,
    };
    stream.set_nodelay(true).map_err(err)?;
    stream.set_read_timeout(Some(POLL_INTERVAL)).map_err(err)?;
    let writer = stream.try_clone().map_err(err)?;
    Ok(Duplex {
        reader: Box::new(stream),
        writer: Box::new(writer),
        name: format!("tcp {addr}"),
    })
}

/// Connects to a TCP peer.
pub fn tcp_connect(addr: impl ToSocketAddrs + std::fmt::Debug) -> Result<Duplex, TransportError> {
    // Debug, as `ToSocketAddrs` has no Display; a plain address loses its quotes.
    let name = format!("{addr:?}").trim_matches('"').to_string();
    let stream = TcpStream::connect(&addr).map_err(|source| {
        // A board that is busy refuses as one that is not there: both are named.
        if source.kind() == io::ErrorKind::ConnectionRefused {
            TransportError::TcpRefused {
                addr: name.clone(),
                source,
            }
        } else {
            TransportError::Tcp {
                what: "connect to",
                addr: name.clone(),
                source,
            }
        }
    })?;
    tcp_duplex(stream, name, "connect to")
}

/// Accepts one TCP connection on `listener`.
pub fn tcp_accept(listener: &TcpListener) -> Result<Duplex, TransportError> {
    let name = listener
        .local_addr()
        .map(|a| a.to_string())
        .unwrap_or_default();
    let (stream, peer) = listener.accept().map_err(|source| TransportError::Tcp {
        what: "listen on",
        addr: name.clone(),
        source,
    })?;
    tcp_duplex(stream, format!("{name} from {peer}"), "listen on")
}

/// Standard input and output (for running the simulated board as a child process).
pub fn stdio() -> Duplex {
    Duplex {
        reader: Box::new(io::stdin()),
        writer: Box::new(io::stdout()),
        name: "stdio".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pty_pair_carries_bytes_both_ways_and_reports_close() {
        let (mut host, mut board) = pty_pair().unwrap();
        host.writer.write_all(&[1, 2, 0, 255]).unwrap();
        let mut got = [0u8; 4];
        board.reader.read_exact(&mut got).unwrap();
        assert_eq!(got, [1, 2, 0, 255]);
        board.writer.write_all(b"ok").unwrap();
        let mut got = [0u8; 2];
        host.reader.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"ok");
        drop(host);
        let mut buf = [0u8; 8];
        assert_eq!(board.reader.read(&mut buf).unwrap(), 0);
    }

    /// Issue 54: a program started while the pair is open (ffmpeg for a video) no longer
    /// holds it: the host's close reaches the board while that program still runs.
    #[test]
    fn a_child_process_does_not_hold_the_pty_open() {
        let (host, mut board) = pty_pair().unwrap();
        let mut child = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .expect("start sleep");
        drop(host);
        let mut buf = [0u8; 8];
        // Reads time out every poll interval until the hang-up, which comes at once.
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
        let eof = loop {
            match board.reader.read(&mut buf) {
                Ok(0) => break true,
                Err(e) if is_poll_timeout(&e) && std::time::Instant::now() < deadline => {}
                _ => break false,
            }
        };
        let running = child.try_wait().unwrap().is_none();
        let _ = child.kill();
        let _ = child.wait();
        assert!(
            eof && running,
            "the hang-up waited for the child (eof {eof})"
        );
    }

    #[test]
    fn tcp_loopback_carries_bytes() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let t = std::thread::spawn(move || tcp_accept(&listener).unwrap());
        let mut host = tcp_connect(addr).unwrap();
        let mut board = t.join().unwrap();
        host.writer.write_all(&[0, 7]).unwrap();
        let mut got = [0u8; 2];
        board.reader.read_exact(&mut got).unwrap();
        assert_eq!(got, [0, 7]);
    }

    #[test]
    fn missing_serial_device_names_the_path() {
        let err = serial("/dev/does-not-exist-ttyX", 115_200).err().unwrap();
        assert!(
            err.to_string().contains("/dev/does-not-exist-ttyX"),
            "{err}"
        );
    }
}

/// What a noisy line ([`noisy_writer`]) did to the bytes written through it.
#[derive(Debug, Default)]
pub struct LineDamage {
    /// Bytes garbled (one bit flipped each).
    pub bytes: std::sync::atomic::AtomicU64,
    /// Frames (as written: each ends at a 0x00 delimiter) with at least one garbled byte.
    pub frames: std::sync::atomic::AtomicU64,
}

impl LineDamage {
    /// `(bytes, frames)` garbled so far.
    pub fn counts(&self) -> (u64, u64) {
        use std::sync::atomic::Ordering::Relaxed;
        (self.bytes.load(Relaxed), self.frames.load(Relaxed))
    }
}

/// A writer whose line garbles bytes, as a long cable or a noisy ground does: each byte has one
/// random bit flipped with probability `byte_error_rate`, from a seeded generator (a run is
/// repeatable). What it did is counted in `damage`.
pub fn noisy_writer(
    inner: Box<dyn Write + Send>,
    byte_error_rate: f64,
    seed: u64,
    damage: std::sync::Arc<LineDamage>,
) -> Box<dyn Write + Send> {
    use rand::SeedableRng;
    Box::new(NoisyWriter {
        inner,
        rate: byte_error_rate,
        rng: rand::rngs::StdRng::seed_from_u64(seed),
        damage,
        frame_hit: false,
        buf: Vec::new(),
    })
}

struct NoisyWriter {
    inner: Box<dyn Write + Send>,
    rate: f64,
    rng: rand::rngs::StdRng,
    damage: std::sync::Arc<LineDamage>,
    /// Whether the frame being written has a garbled byte yet.
    frame_hit: bool,
    buf: Vec<u8>,
}

impl Write for NoisyWriter {
    fn write(&mut self, bytes: &[u8]) -> io::Result<usize> {
        use rand::RngExt as _;
        use std::sync::atomic::Ordering::Relaxed;
        self.buf.clear();
        self.buf.extend_from_slice(bytes);
        for b in &mut self.buf {
            let delimiter = *b == 0;
            if self.rng.random::<f64>() < self.rate {
                *b ^= 1 << self.rng.random_range(0..8u32);
                self.damage.bytes.fetch_add(1, Relaxed);
                self.frame_hit = true;
            }
            if delimiter {
                if self.frame_hit {
                    self.damage.frames.fetch_add(1, Relaxed);
                }
                self.frame_hit = false;
            }
        }
        self.inner.write_all(&self.buf)?;
        Ok(bytes.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}
