//! The host's links to a fusion core on a board, each a [`tracker::CoreTransport`]: the
//! simulated board in-process on a pty pair, the same board called directly (no pty, no
//! thread; with its reset line and a simulated IMU), a serial device, a TCP peer, or the
//! firmware under QEMU. On a byte transport a reader thread decodes the core's frames as they
//! arrive, so the core never blocks on a full line while the host is busy with a frame.
//!
//! The tracker itself knows none of them: it runs any transport, and its own in-process core
//! ([`tracker::InProcessCore`]) needs no board. This crate is what an application adds to
//! reach a board (`host-vision --link`, the Python module's `link=`).

use std::cell::RefCell;
use std::collections::VecDeque;
use std::io::{self, Write};
use std::path::PathBuf;
use std::str::FromStr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, TryRecvError, channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use firmware_sim::board::{self, Board, BoardReport, Precision, ResetPin};
use firmware_sim::qemu::QemuBoard;
use firmware_sim::transport::{self, Duplex};
use protocol::io::{FrameReader, FrameWriter, RecvError};
use protocol::{CoreToHost, HostToCore};

use tracker::{CoreTransport, Incoming, TrackerError};

/// Where the core is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkSpec {
    /// The simulated board on a pty pair in this process.
    Sim(Precision),
    /// The simulated board called directly in this process: the frames as bytes into its
    /// device loop, its answers decoded at once; no pty and no thread, so deterministic.
    InProcess(Precision),
    /// A serial device (hardware board, or a simulated board in another process).
    Serial {
        /// Device path, or a pattern (`/dev/ttyUSB*`): each connection opens the first
        /// device it matches that opens, so an adaptor that comes back under another name is
        /// found again.
        path: String,
        /// Baud rate.
        baud: u32,
    },
    /// A TCP peer (`firmware-sim --link tcp:ADDR`).
    Tcp(String),
    /// The firmware image under QEMU's Cortex-M4F board.
    Qemu(PathBuf),
    /// The repository's firmware image under QEMU: the application finds it
    /// ([`LinkSpec::resolve_qemu`]) before the link opens.
    QemuDefault,
}

/// The command line's forms of a link, for help texts and errors.
pub const LINK_FORMS: &str =
    "sim, sim:f64, inproc, inproc:f64, serial:PATH[@BAUD], tcp:HOST:PORT, qemu or qemu:IMAGE";

/// Baud rate of `serial:PATH` without `@BAUD` (the least the IMU and correspondence traffic
/// needs, PROTOCOL.md §6).
pub const DEFAULT_BAUD: u32 = 921_600;

impl LinkSpec {
    /// This spec with the repository's firmware image in place of [`LinkSpec::QemuDefault`],
    /// found by `find`; any other spec as it is.
    pub fn resolve_qemu(
        &self,
        find: impl FnOnce() -> Result<PathBuf, String>,
    ) -> Result<LinkSpec, String> {
        match self {
            LinkSpec::QemuDefault => find().map(LinkSpec::Qemu),
            other => Ok(other.clone()),
        }
    }
}

impl std::fmt::Display for LinkSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LinkSpec::Sim(Precision::F32) => {
                write!(f, "sim (f32 core in this process, on a pty pair)")
            }
            LinkSpec::Sim(Precision::F64) => {
                write!(f, "sim:f64 (f64 core in this process, on a pty pair)")
            }
            LinkSpec::InProcess(Precision::F32) => {
                write!(f, "inproc (f32 core called directly in this process)")
            }
            LinkSpec::InProcess(Precision::F64) => {
                write!(f, "inproc:f64 (f64 core called directly in this process)")
            }
            LinkSpec::Serial { path, baud } => write!(f, "serial {path} at {baud} baud"),
            LinkSpec::Tcp(addr) => write!(f, "tcp {addr}"),
            LinkSpec::Qemu(image) => write!(f, "qemu {}", image.display()),
            LinkSpec::QemuDefault => write!(f, "qemu (the repository's firmware image)"),
        }
    }
}

impl FromStr for LinkSpec {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "sim" | "sim:f32" => return Ok(LinkSpec::Sim(Precision::F32)),
            "sim:f64" => return Ok(LinkSpec::Sim(Precision::F64)),
            "inproc" | "inproc:f32" => return Ok(LinkSpec::InProcess(Precision::F32)),
            "inproc:f64" => return Ok(LinkSpec::InProcess(Precision::F64)),
            "qemu" => return Ok(LinkSpec::QemuDefault),
            _ => {}
        }
        if let Some(rest) = s.strip_prefix("serial:") {
            let (path, baud) = match rest.rsplit_once('@') {
                Some((p, b)) => (
                    p,
                    b.parse()
                        .map_err(|e| format!("baud rate `{b}` in `{s}`: {e}"))?,
                ),
                None => (rest, DEFAULT_BAUD),
            };
            if path.is_empty() {
                return Err(format!("`{s}`: no device path"));
            }
            return Ok(LinkSpec::Serial {
                path: path.into(),
                baud,
            });
        }
        if let Some(addr) = s.strip_prefix("tcp:") {
            return match addr.rsplit_once(':') {
                Some((host, port)) if !host.is_empty() && port.parse::<u16>().is_ok() => {
                    Ok(LinkSpec::Tcp(addr.into()))
                }
                _ => Err(format!(
                    "`{s}`: expected tcp:HOST:PORT, e.g. tcp:127.0.0.1:7000"
                )),
            };
        }
        if let Some(image) = s.strip_prefix("qemu:") {
            if image.is_empty() {
                return Err(format!("`{s}`: no image path"));
            }
            return Ok(LinkSpec::Qemu(image.into()));
        }
        Err(format!("unknown link `{s}`: expected {LINK_FORMS}"))
    }
}

/// The host's end of the link to a core, across reconnections: the current connection (if
/// the link is up), and what it takes to make a new one (the spec, the in-process board,
/// QEMU).
pub struct CoreLink {
    spec: LinkSpec,
    name: String,
    conn: Option<Connection>,
    board: Option<SimBoard>,
    /// The board called directly (`LinkSpec::InProcess`), with its reset line.
    local: Option<(Board, ResetPin)>,
    qemu: Option<QemuBoard>,
    /// `(byte error rate, seed)` of the injected line noise.
    noise: Option<(f64, u64)>,
    /// Messages sent.
    pub messages_out: u64,
    /// Connections made: the first, then one per reconnection.
    pub connections: u32,
    /// With bit errors injected on the line: what they did, to the core and to the host.
    pub damage: Option<LineNoise>,
}

/// One connection.
enum Connection {
    /// Bytes on a transport, with a reader thread.
    Threaded(Threaded),
    /// The board called directly: the frames it answered, decoded, wait here.
    InProcess {
        /// Encodes each message (into its own buffer).
        writer: FrameWriter<Vec<u8>>,
        /// The core's answers not yet taken.
        answers: RefCell<VecDeque<Incoming>>,
    },
}

/// A connection on a byte transport: the framed writer, and the reader thread with its
/// channel. Dropping it closes the host's end (the core sees the line hang up) and joins the
/// reader.
struct Threaded {
    writer: FrameWriter<Box<dyn Write + Send>>,
    rx: Receiver<Result<Incoming, String>>,
    stop: Arc<AtomicBool>,
    reader: Option<JoinHandle<()>>,
}

impl Drop for Threaded {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
    }
}

/// The simulated board of a `sim` link, on its own thread in this process: it takes each new
/// connection from `connect`, keeping its core between them, and is reset through `pin`.
struct SimBoard {
    connect: Option<Sender<Duplex>>,
    pin: ResetPin,
    handle: Option<JoinHandle<io::Result<BoardReport>>>,
}

/// Bit errors injected on the line to the simulated board (a long cable, a noisy ground).
#[derive(Debug, Clone)]
pub struct LineNoise {
    /// Probability that a byte has one bit flipped, in either direction.
    pub byte_error_rate: f64,
    /// What the line did to the host's bytes.
    pub to_core: Arc<transport::LineDamage>,
    /// What the line did to the core's bytes.
    pub to_host: Arc<transport::LineDamage>,
}

impl std::fmt::Debug for CoreLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CoreLink")
            .field("name", &self.name)
            .field("connected", &self.conn.is_some())
            .finish()
    }
}

impl CoreLink {
    /// Opens the link (starting the simulated board or QEMU where asked).
    pub fn open(spec: &LinkSpec) -> Result<Self, TrackerError> {
        Self::open_noisy(spec, None)
    }

    /// Opens the link with bit errors `(byte error rate, seed)` injected in both directions
    /// (the simulated board's link only).
    pub fn open_noisy(spec: &LinkSpec, noise: Option<(f64, u64)>) -> Result<Self, TrackerError> {
        if let Some((rate, _)) = noise {
            if !matches!(spec, LinkSpec::Sim(_)) {
                return Err(TrackerError::Config(format!(
                    "bit errors are injected on the simulated board's line only (the sim link), not on {spec}"
                )));
            }
            if !(rate.is_finite() && (0.0..=1.0).contains(&rate)) {
                return Err(TrackerError::Config(format!(
                    "the line's bit error rate is a probability per byte in [0, 1], got {rate}"
                )));
            }
        }
        let spec = match spec {
            LinkSpec::QemuDefault => {
                return Err(TrackerError::Config(
                    "link qemu: which firmware image? Give its path (LinkSpec::Qemu), or resolve the default one first (LinkSpec::resolve_qemu)".into(),
                ));
            }
            other => other.clone(),
        };
        let board = match &spec {
            LinkSpec::Sim(precision) => {
                let (connect, connections) = channel();
                let pin = ResetPin::default();
                let handle =
                    board::spawn_serving(connections, *precision, pin.clone()).map_err(|e| {
                        TrackerError::Core(format!("starting the simulated board: {e}"))
                    })?;
                Some(SimBoard {
                    connect: Some(connect),
                    pin,
                    handle: Some(handle),
                })
            }
            _ => None,
        };
        let local = match &spec {
            LinkSpec::InProcess(precision) => {
                let pin = ResetPin::default();
                Some((Board::new(*precision, pin.clone()), pin))
            }
            _ => None,
        };
        let mut link = CoreLink {
            name: spec.to_string(),
            spec,
            conn: None,
            board,
            local,
            qemu: None,
            noise,
            messages_out: 0,
            connections: 0,
            damage: noise.map(|(rate, _)| LineNoise {
                byte_error_rate: rate,
                to_core: Arc::default(),
                to_host: Arc::default(),
            }),
        };
        link.connect()?;
        Ok(link)
    }

    /// Makes a new connection of the link's kind (after the current one, if any, is closed).
    fn connect(&mut self) -> Result<(), TrackerError> {
        self.conn = None;
        let duplex = match &self.spec {
            LinkSpec::Sim(_) => {
                let (mut host, mut board_end) = transport::pty_pair().map_err(opening)?;
                if let (Some((rate, seed)), Some(d)) = (self.noise, &self.damage) {
                    // Each connection's line garbles differently, and repeatably.
                    let seed = seed.wrapping_add(u64::from(self.connections));
                    host.writer =
                        transport::noisy_writer(host.writer, rate, seed, d.to_core.clone());
                    board_end.writer = transport::noisy_writer(
                        board_end.writer,
                        rate,
                        seed ^ 0x5EED,
                        d.to_host.clone(),
                    );
                }
                let sent = self
                    .board
                    .as_ref()
                    .and_then(|b| b.connect.as_ref())
                    .is_some_and(|c| c.send(board_end).is_ok());
                if !sent {
                    return Err(TrackerError::Core("the simulated board has stopped".into()));
                }
                host
            }
            LinkSpec::InProcess(_) => {
                if let Some((board, _)) = &mut self.local {
                    board.open_session();
                }
                self.name = self.spec.to_string();
                self.conn = Some(Connection::InProcess {
                    writer: FrameWriter::new(Vec::new()),
                    answers: RefCell::new(VecDeque::new()),
                });
                self.connections += 1;
                return Ok(());
            }
            LinkSpec::Serial { path, baud } => open_serial(path, *baud)?,
            LinkSpec::Tcp(addr) => transport::tcp_connect(addr.as_str()).map_err(opening)?,
            LinkSpec::Qemu(image) => {
                // A new connection to QEMU's UART is a new QEMU: the board boots again.
                self.qemu = None;
                let (q, duplex) = QemuBoard::start(image, Duration::from_secs(20))
                    .map_err(|e| TrackerError::Core(e.to_string()))?;
                self.qemu = Some(q);
                duplex
            }
            LinkSpec::QemuDefault => unreachable!("resolved when the link was opened"),
        };
        self.name = duplex.name.clone();
        self.conn = Some(Connection::start(duplex));
        self.connections += 1;
        Ok(())
    }

    /// Opens the link again after it was lost: a new pty to the simulated board, the serial
    /// device opened again, a new TCP connection, or QEMU started again (which boots the
    /// firmware: a reset).
    /// Every failure is a [`TrackerError::Link`]: the caller tries again later.
    pub fn reconnect(&mut self) -> Result<(), TrackerError> {
        self.connect().map_err(|e| match e {
            TrackerError::Link(e) => TrackerError::Link(e),
            other => TrackerError::Link(format!("reconnecting to {}: {other}", self.spec)),
        })
    }

    /// Whether a connection is open.
    pub fn is_connected(&self) -> bool {
        self.conn.is_some()
    }

    /// Fault injection: closes the host's end of the line, as a pulled cable does. The core
    /// is not told; the simulated board waits for the next connection with its state.
    pub fn cut(&mut self) {
        self.conn = None;
    }

    /// Fault injection: resets the core (the simulated board's reset line, or QEMU killed:
    /// the next connection boots the firmware again).
    pub fn reset_core(&mut self) -> Result<(), TrackerError> {
        if let Some(b) = &self.board {
            b.pin.pulse();
            return Ok(());
        }
        if let Some((_, pin)) = &self.local {
            pin.pulse();
            return Ok(());
        }
        if self.qemu.take().is_some() {
            return Ok(());
        }
        Err(TrackerError::Config(format!(
            "the host cannot reset the core on {}: only sim, inproc and qemu links have a reset line",
            self.spec
        )))
    }

    /// The transport's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    fn conn(&self) -> Result<&Connection, TrackerError> {
        self.conn
            .as_ref()
            .ok_or_else(|| TrackerError::Link(format!("link {} is down", self.name)))
    }

    /// Sends one message.
    pub fn send(&mut self, msg: &HostToCore) -> Result<(), TrackerError> {
        let name = &self.name;
        let conn = self
            .conn
            .as_mut()
            .ok_or_else(|| TrackerError::Link(format!("link {name} is down")))?;
        let failed = |e: io::Error| TrackerError::Link(format!("link {name}: write failed: {e}"));
        match conn {
            Connection::Threaded(t) => t.writer.send(msg).map_err(failed)?,
            Connection::InProcess { writer, answers } => {
                writer.send(msg).map_err(failed)?;
                let bytes = std::mem::take(writer.get_mut());
                let (board, _) = self
                    .local
                    .as_mut()
                    .ok_or_else(|| TrackerError::Link(format!("link {name}: no board")))?;
                let mut out = Vec::new();
                board.receive(&bytes, &mut out);
                board.delivered(out.len());
                queue_answers(out, answers);
            }
        }
        self.messages_out += 1;
        Ok(())
    }

    /// Fits the in-process board with a simulated ICM-42688-P at `settings`
    /// (`track --imu-on-core`): the core may then sample its own IMU. Other links' boards
    /// have the IMU they were built with.
    pub fn fit_simulated_imu(&mut self, settings: icm42688::Settings) -> Result<(), TrackerError> {
        let (board, _) = self.local.as_mut().ok_or_else(|| {
            TrackerError::Config(format!(
                "link {}: only the in-process board (inproc) has a simulated IMU to fit",
                self.name
            ))
        })?;
        board.fit_imu(settings, 0).map_err(TrackerError::Core)
    }

    /// One reading into the in-process board's simulated IMU at the board's time `t_us`: the
    /// board's sample path reads it into the core, whose messages wait for the host as its
    /// answers do. Returns whether the core triggered the camera.
    pub fn simulated_imu_sample(
        &mut self,
        t_us: u64,
        gyro: [f64; 3],
        accel: [f64; 3],
    ) -> Result<bool, TrackerError> {
        let name = &self.name;
        let (Some((board, _)), Some(Connection::InProcess { answers, .. })) =
            (self.local.as_mut(), self.conn.as_ref())
        else {
            return Err(TrackerError::Link(format!(
                "link {name}: no in-process board connected to sample"
            )));
        };
        let mut out = Vec::new();
        let triggered = board
            .imu_sample(t_us, gyro, accel, &mut out)
            .map_err(TrackerError::Core)?;
        board.delivered(out.len());
        queue_answers(out, answers);
        Ok(triggered)
    }

    /// Waits up to `timeout` for the next item.
    pub fn recv(&self, timeout: Duration) -> Result<Incoming, TrackerError> {
        self.recv_within(timeout)?.ok_or_else(|| {
            TrackerError::Link(format!(
                "link {}: no answer from the core within {timeout:?}",
                self.name
            ))
        })
    }

    /// Waits up to `timeout` for the next item; `None` if none came.
    pub fn recv_within(&self, timeout: Duration) -> Result<Option<Incoming>, TrackerError> {
        let t = match self.conn()? {
            Connection::Threaded(t) => t,
            // The core answered when it was called: what is not here will not come.
            Connection::InProcess { answers, .. } => return Ok(answers.borrow_mut().pop_front()),
        };
        match t.rx.recv_timeout(timeout) {
            Ok(Ok(m)) => Ok(Some(m)),
            Ok(Err(e)) => Err(TrackerError::Link(format!("link {}: {e}", self.name))),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(TrackerError::Link(format!(
                "link {}: reader stopped",
                self.name
            ))),
        }
    }

    /// The next item if one is waiting.
    pub fn try_recv(&self) -> Result<Option<Incoming>, TrackerError> {
        let t = match self.conn()? {
            Connection::Threaded(t) => t,
            Connection::InProcess { answers, .. } => return Ok(answers.borrow_mut().pop_front()),
        };
        match t.rx.try_recv() {
            Ok(Ok(m)) => Ok(Some(m)),
            Ok(Err(e)) => Err(TrackerError::Link(format!("link {}: {e}", self.name))),
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => Err(TrackerError::Link(format!(
                "link {}: reader stopped",
                self.name
            ))),
        }
    }

    /// Closes the link and waits for the simulated board (whose report is returned) or
    /// stops QEMU.
    pub fn close(mut self) -> Result<Option<BoardReport>, TrackerError> {
        self.shutdown()
    }

    fn shutdown(&mut self) -> Result<Option<BoardReport>, TrackerError> {
        // Dropping our last descriptors of the line ends the board's session; dropping the
        // board's connection channel ends the board.
        self.conn = None;
        self.qemu = None;
        if let Some((board, _)) = self.local.take() {
            return Ok(Some(board.report()));
        }
        let Some(board) = self.board.as_mut() else {
            return Ok(None);
        };
        board.connect = None;
        let Some(handle) = board.handle.take() else {
            return Ok(None);
        };
        let deadline = Instant::now() + Duration::from_secs(10);
        while !handle.is_finished() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(5));
        }
        if !handle.is_finished() {
            return Err(TrackerError::Core(
                "the simulated board did not end its session".into(),
            ));
        }
        match handle.join() {
            Ok(Ok(report)) => Ok(Some(report)),
            Ok(Err(e)) => Err(TrackerError::Core(format!("simulated board: {e}"))),
            Err(_) => Err(TrackerError::Core("simulated board panicked".into())),
        }
    }
}

/// Opens the serial device `path`, or, if it is a pattern (`/dev/ttyUSB*`, as a USB adaptor
/// plugged in again may come back under another name), the first device it matches that
/// opens.
fn open_serial(path: &str, baud: u32) -> Result<Duplex, TrackerError> {
    if !path.contains(['*', '?', '[']) {
        return transport::serial(path, baud).map_err(opening);
    }
    let matches = glob::glob(path)
        .map_err(|e| TrackerError::Config(format!("serial:{path}: bad pattern: {e}")))?;
    let mut failures = Vec::new();
    for m in matches.flatten() {
        let device = m.to_string_lossy().into_owned();
        match transport::serial(&device, baud) {
            Ok(d) => return Ok(d),
            Err(e) => failures.push(e.to_string()),
        }
    }
    Err(TrackerError::Link(if failures.is_empty() {
        format!("no serial device matches {path}")
    } else {
        format!("no device matching {path} opens: {}", failures.join("; "))
    }))
}

/// A transport that could not be opened.
fn opening(e: transport::TransportError) -> TrackerError {
    TrackerError::Transport(Box::new(e))
}

impl Connection {
    /// Starts the reader thread of `duplex`, which decodes the core's frames as they arrive.
    fn start(duplex: Duplex) -> Self {
        Connection::Threaded(Threaded::start(duplex))
    }
}

impl Threaded {
    /// See [`Connection::start`].
    fn start(duplex: Duplex) -> Self {
        let Duplex { reader, writer, .. } = duplex;
        let (tx, rx) = channel();
        let stop = Arc::new(AtomicBool::new(false));
        let stop_reader = stop.clone();
        let reader = std::thread::Builder::new()
            .name("core reader".into())
            .spawn(move || {
                let mut r = FrameReader::new(reader);
                loop {
                    let item = match r.recv::<CoreToHost>() {
                        Ok(m) => Ok(Incoming::Message(m)),
                        Err(RecvError::Frame(e)) => Ok(Incoming::Rejected(e)),
                        Err(RecvError::Io(e)) if transport::is_poll_timeout(&e) => {
                            if stop_reader.load(Ordering::Relaxed) {
                                return;
                            }
                            continue;
                        }
                        Err(RecvError::Io(e)) => Err(format!("I/O error: {e}")),
                        Err(RecvError::Closed { partial }) => Err(format!(
                            "closed by the core ({partial} bytes of an unfinished frame lost)"
                        )),
                    };
                    let end = item.is_err();
                    if tx.send(item).is_err() || end {
                        return;
                    }
                }
            })
            .ok();
        Threaded {
            writer: FrameWriter::new(writer),
            rx,
            stop,
            reader,
        }
    }
}

/// Decodes the in-process board's answers (whole frames) into the queue the host reads.
fn queue_answers(bytes: Vec<u8>, answers: &RefCell<VecDeque<Incoming>>) {
    let mut reader = FrameReader::new(io::Cursor::new(bytes));
    let mut answers = answers.borrow_mut();
    loop {
        match reader.recv::<CoreToHost>() {
            Ok(m) => answers.push_back(Incoming::Message(m)),
            Err(RecvError::Frame(e)) => answers.push_back(Incoming::Rejected(e)),
            // All the answers taken (the core answers whole frames).
            Err(_) => break,
        }
    }
}

impl Drop for CoreLink {
    fn drop(&mut self) {
        let _ = self.shutdown();
    }
}

impl CoreTransport for CoreLink {
    fn name(&self) -> &str {
        CoreLink::name(self)
    }

    fn send(&mut self, msg: &HostToCore) -> Result<(), TrackerError> {
        CoreLink::send(self, msg)
    }

    fn recv_within(&mut self, timeout: Duration) -> Result<Option<Incoming>, TrackerError> {
        CoreLink::recv_within(self, timeout)
    }

    fn try_recv(&mut self) -> Result<Option<Incoming>, TrackerError> {
        CoreLink::try_recv(self)
    }

    fn reconnect(&mut self) -> Result<(), TrackerError> {
        CoreLink::reconnect(self)
    }

    fn lossy(&self) -> bool {
        self.damage.is_some()
    }

    fn is_connected(&self) -> bool {
        CoreLink::is_connected(self)
    }

    fn disconnect(&mut self) {
        self.cut();
    }
}
