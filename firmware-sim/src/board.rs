//! The simulated board: `fusion-core`'s device loop ([`DeviceIo`]) behind a byte transport,
//! exactly as the firmware runs it behind its UART.
//!
//! The board only reacts to bytes: pacing is the host's. In lock-step replay the host streams
//! recorded IMU samples as fast as the link takes them and holds each frame's correspondences
//! for a simulated latency; in real time it paces the samples by the clock. Either way the
//! board's answers depend only on the bytes it received, so a replay is deterministic.

use std::io::{self, Read as _, Write as _};
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc::Receiver;
use std::thread::JoinHandle;

use fusion_core::device::{Counters, DeviceIo};
use icm42688::Settings;
use protocol::CoreToHost;

use crate::sim::sensor_board::SimulatedImu;

use crate::transport::{self, Duplex};

/// Floating-point width of the simulated core.
pub use fusion_core::Precision;

/// What the board did, over all its sessions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoardReport {
    /// Bytes received.
    pub bytes_in: u64,
    /// Bytes sent.
    pub bytes_out: u64,
    /// Connections served.
    pub sessions: u32,
    /// Resets through the [`ResetPin`] (each a new core with nothing of the old one).
    pub resets: u32,
    /// The device's counters at the end (since the last reset).
    pub counters: Counters,
    /// The model the core was configured with, if it was: the vision-only model's clock is
    /// ticks, not IMU samples (`Counters::imu_applied` counts either).
    pub model: Option<protocol::ModelKind>,
}

/// The board's reset line, for fault injection: each [`ResetPin::pulse`] power-cycles the
/// core before it handles the next bytes, as a brown-out or a watchdog does (what it held is
/// gone, bytes in flight included).
#[derive(Clone, Debug, Default)]
pub struct ResetPin(Arc<AtomicU32>);

impl ResetPin {
    /// Requests a reset.
    pub fn pulse(&self) {
        self.0.fetch_add(1, Ordering::SeqCst);
    }

    /// Resets requested and not yet applied, cleared.
    fn take(&self) -> u32 {
        self.0.swap(0, Ordering::SeqCst)
    }
}

/// One simulated board: a fusion core that outlives the connections to it, as a powered
/// board outlives its host's process and its cable.
pub struct Board {
    core: Core,
    pin: ResetPin,
    report: BoardReport,
    /// The board's own IMU, where it has one ([`Board::fit_imu`]).
    imu: Option<SimulatedImu>,
}

/// The device, of either width. On the heap: the f64 device is 26 KB.
enum Core {
    F32(Box<DeviceIo<f32>>),
    F64(Box<DeviceIo<f64>>),
}

impl std::fmt::Debug for Board {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Board")
            .field("report", &self.report)
            .finish()
    }
}

impl Board {
    /// A board just powered on, with its reset line `pin`.
    pub fn new(precision: Precision, pin: ResetPin) -> Self {
        let mut board = Board {
            core: Core::F32(Box::default()),
            pin,
            report: BoardReport {
                bytes_in: 0,
                bytes_out: 0,
                sessions: 0,
                resets: 0,
                counters: Counters::default(),
                model: None,
            },
            imu: None,
        };
        board.power_on(precision);
        board
    }

    fn power_on(&mut self, precision: Precision) {
        self.core = match precision {
            Precision::F32 => Core::F32(Box::default()),
            Precision::F64 => Core::F64(Box::default()),
        };
        // The core that boots knows its board's wiring.
        let fitted = self.imu.is_some();
        match &mut self.core {
            Core::F32(io) => io.device.set_onboard_imu(fitted),
            Core::F64(io) => io.device.set_onboard_imu(fitted),
        }
    }

    /// Fits the board with a simulated ICM-42688-P at `settings` (protocol/PROTOCOL.md §7),
    /// configured at MCU time `now_us`: the core then may sample it when the host asks.
    pub fn fit_imu(&mut self, settings: Settings, now_us: u64) -> Result<(), String> {
        self.imu = Some(SimulatedImu::start(settings, now_us)?);
        self.power_on(self.precision());
        Ok(())
    }

    /// One reading taken by the board's IMU at MCU time `t_us`, through its sample path into
    /// the core; the core's messages, as encoded frames, are appended to `out`. Returns
    /// whether the camera was triggered. A board without an IMU fails.
    pub fn imu_sample(
        &mut self,
        t_us: u64,
        gyro: [f64; 3],
        accel: [f64; 3],
        out: &mut Vec<u8>,
    ) -> Result<bool, String> {
        let imu = self.imu.as_mut().ok_or("the board has no IMU of its own")?;
        let mut buf = vec![0u8; protocol::limits::MAX_FRAME_LEN];
        let mut send = |m: CoreToHost| {
            if let Ok(frame) = protocol::encode_frame(&m, &mut buf) {
                out.extend_from_slice(frame);
            }
        };
        match &mut self.core {
            Core::F32(io) => imu.sample(t_us, gyro, accel, &mut io.device, &mut send),
            Core::F64(io) => imu.sample(t_us, gyro, accel, &mut io.device, &mut send),
        }
    }

    fn precision(&self) -> Precision {
        match self.core {
            Core::F32(_) => Precision::F32,
            Core::F64(_) => Precision::F64,
        }
    }

    /// What the board did so far.
    pub fn report(&self) -> BoardReport {
        let (counters, model) = match &self.core {
            Core::F32(io) => (*io.device.counters(), io.device.params().map(|p| p.model)),
            Core::F64(io) => (*io.device.counters(), io.device.params().map(|p| p.model)),
        };
        BoardReport {
            counters,
            model,
            ..self.report
        }
    }

    /// A new session begins (a connection, or a host in the same process attaching): its
    /// host must shake hands before it drives the core, which keeps its state.
    pub fn open_session(&mut self) {
        self.report.sessions += 1;
        match &mut self.core {
            Core::F32(io) => io.link_opened(),
            Core::F64(io) => io.link_opened(),
        }
    }

    /// Takes `bytes` from the host: a reset requested on the pin first (what the core held is
    /// gone, as after a brown-out), then the core; its answers, as encoded frames, are
    /// appended to `out`.
    pub fn receive(&mut self, bytes: &[u8], out: &mut Vec<u8>) {
        let resets = self.pin.take();
        if resets > 0 {
            self.report.resets += resets;
            self.power_on(self.precision());
        }
        self.report.bytes_in += bytes.len() as u64;
        let mut send = |frame: &[u8]| out.extend_from_slice(frame);
        match &mut self.core {
            Core::F32(io) => io.receive(bytes, &mut send),
            Core::F64(io) => io.receive(bytes, &mut send),
        }
    }

    /// Counts `n` bytes of answers that reached the host.
    pub fn delivered(&mut self, n: usize) {
        self.report.bytes_out += n as u64;
    }

    /// Serves one connection until the host closes it; the core keeps its state for the next.
    /// A transport error ends the connection with that error.
    pub fn serve(&mut self, link: Duplex) -> io::Result<()> {
        self.open_session();
        let Duplex {
            mut reader,
            mut writer,
            ..
        } = link;
        let mut buf = [0u8; 4096];
        let mut out = Vec::with_capacity(4096);
        loop {
            let n = match reader.read(&mut buf) {
                Ok(0) => return Ok(()),
                Ok(n) => n,
                Err(e) if transport::is_poll_timeout(&e) => continue,
                // The host hung up.
                Err(e) if transport::is_hang_up(&e) => return Ok(()),
                Err(e) => return Err(e),
            };
            out.clear();
            self.receive(&buf[..n], &mut out);
            if !out.is_empty() {
                match writer.write_all(&out).and_then(|_| writer.flush()) {
                    Ok(()) => self.delivered(out.len()),
                    // The host hung up while answers were in flight.
                    Err(e) if transport::is_hang_up(&e) => return Ok(()),
                    Err(e) => return Err(e),
                }
            }
        }
    }
}

/// Serves one session on `link` until the host closes it, on a new board.
///
/// Returns the report on a clean end of stream; a transport error ends the session with that
/// error.
pub fn serve(link: Duplex, precision: Precision) -> io::Result<BoardReport> {
    let mut board = Board::new(precision, ResetPin::default());
    board.serve(link)?;
    Ok(board.report())
}

/// Runs [`serve`] on its own thread (named after the link).
pub fn spawn(
    link: Duplex,
    precision: Precision,
) -> io::Result<JoinHandle<io::Result<BoardReport>>> {
    std::thread::Builder::new()
        .name(format!("board {}", link.name))
        .spawn(move || serve(link, precision))
}

/// Runs one board on its own thread, serving the connections that arrive on `connections`
/// one after another with the same core (a cable pulled and plugged back in, a host
/// restarted), until the sender is dropped. `pin` resets it.
pub fn spawn_serving(
    connections: Receiver<Duplex>,
    precision: Precision,
    pin: ResetPin,
) -> io::Result<JoinHandle<io::Result<BoardReport>>> {
    std::thread::Builder::new()
        .name("board".into())
        .spawn(move || {
            let mut board = Board::new(precision, pin);
            for link in connections {
                board.serve(link)?;
            }
            Ok(board.report())
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::pty_pair;
    use protocol::io::{FrameReader, FrameWriter};
    use protocol::{CoreToHost, Hello, HostToCore, Mode, PROTOCOL_VERSION};

    /// The core's next message, waiting through read timeouts.
    fn next_answer(r: &mut FrameReader<Box<dyn io::Read + Send>>) -> CoreToHost {
        loop {
            match r.recv::<CoreToHost>() {
                Ok(m) => return m,
                Err(protocol::io::RecvError::Io(e)) if transport::is_poll_timeout(&e) => {}
                Err(e) => panic!("{e:?}"),
            }
        }
    }

    #[test]
    fn answers_over_a_pty_and_ends_with_the_session() {
        let (host, board) = pty_pair().unwrap();
        let handle = spawn(board, Precision::F32).unwrap();
        let mut w = FrameWriter::new(host.writer);
        let mut r = FrameReader::new(host.reader);
        let mut recv = || next_answer(&mut r);
        w.send(&HostToCore::Hello(Hello {
            version: PROTOCOL_VERSION,
        }))
        .unwrap();
        assert!(matches!(recv(), CoreToHost::HelloAck(_)));
        w.send(&HostToCore::Configure(protocol::samples::config()))
            .unwrap();
        match recv() {
            CoreToHost::Status(s) => assert_eq!(s.mode, Mode::AwaitingInit),
            other => panic!("{other:?}"),
        }
        // Garbage is answered with a decode error, as by the firmware.
        w.get_mut().write_all(&[0, 1, 2, 3, 0]).unwrap();
        assert!(matches!(recv(), CoreToHost::Error(_)));
        drop(w);
        drop(r);
        let report = handle.join().unwrap().unwrap();
        assert_eq!(report.counters.decode_errors, 1);
        assert!(report.bytes_in > 0 && report.bytes_out > 0);
    }

    /// Issue 55, point 12: who drives the core. The host that holds the link does: a serial
    /// device is opened exclusively, so a second host cannot open it while the first has it;
    /// and a later link must shake hands before it drives the core (a core stayed greeted until
    /// it rebooted, so a second host's `Configure` without a `Hello` was taken).
    #[test]
    fn a_second_host_is_refused_while_the_first_holds_the_core() {
        use crate::transport::{TransportError, pty_for_peer, serial};
        let (board, path) = pty_for_peer().unwrap();
        let handle = spawn(board, Precision::F32).unwrap();
        let first = serial(&path, 115_200).unwrap();
        let mut w = FrameWriter::new(first.writer);
        let mut r = FrameReader::new(first.reader);
        w.send(&HostToCore::Hello(Hello {
            version: PROTOCOL_VERSION,
        }))
        .unwrap();
        assert!(matches!(next_answer(&mut r), CoreToHost::HelloAck(_)));
        let second = serial(&path, 115_200);
        let Err(e @ TransportError::Serial { .. }) = &second else {
            panic!("a second host opened the core's device: {second:?}")
        };
        assert!(e.to_string().contains("another host"), "{e}");
        drop((w, r));
        handle.join().unwrap().unwrap();

        // Over TCP (firmware-sim --forever): the next connection must say `Hello` first.
        let (connect, connections) = std::sync::mpsc::channel();
        let handle = spawn_serving(connections, Precision::F32, ResetPin::default()).unwrap();
        let session = |hello: bool| {
            let (host, board) = pty_pair().unwrap();
            connect.send(board).unwrap();
            let mut w = FrameWriter::new(host.writer);
            let mut r = FrameReader::new(host.reader);
            if hello {
                w.send(&HostToCore::Hello(Hello {
                    version: PROTOCOL_VERSION,
                }))
                .unwrap();
                assert!(matches!(next_answer(&mut r), CoreToHost::HelloAck(_)));
            }
            w.send(&HostToCore::Configure(protocol::samples::config()))
                .unwrap();
            next_answer(&mut r)
        };
        assert!(matches!(session(true), CoreToHost::Status(_)));
        match session(false) {
            CoreToHost::Error(e) => assert_eq!(e.code, protocol::ErrorCode::NoHandshake),
            other => panic!("a host that did not shake hands drove the core: {other:?}"),
        }
        drop(connect);
        handle.join().unwrap().unwrap();
    }

    /// A board keeps its core from one connection to the next (the second host finds the
    /// session), and its reset line leaves it with none.
    #[test]
    fn keeps_its_core_across_connections_until_reset() {
        let (connect, connections) = std::sync::mpsc::channel();
        let pin = ResetPin::default();
        let handle = spawn_serving(connections, Precision::F32, pin.clone()).unwrap();
        let session_of = |configure: bool| {
            let (host, board) = pty_pair().unwrap();
            connect.send(board).unwrap();
            let mut w = FrameWriter::new(host.writer);
            let mut r = FrameReader::new(host.reader);
            let mut recv = || next_answer(&mut r);
            let hello = HostToCore::Hello(Hello {
                version: PROTOCOL_VERSION,
            });
            w.send(&hello).unwrap();
            let CoreToHost::HelloAck(ack) = recv() else {
                panic!("no HelloAck")
            };
            if configure {
                w.send(&HostToCore::Configure(protocol::samples::config()))
                    .unwrap();
                assert!(matches!(recv(), CoreToHost::Status(_)));
            }
            ack.session
        };
        assert_eq!(session_of(true), 0);
        let configured = protocol::samples::config().session;
        assert_eq!(session_of(false), configured);
        pin.pulse();
        assert_eq!(session_of(false), 0);
        drop(connect);
        let report = handle.join().unwrap().unwrap();
        assert_eq!((report.sessions, report.resets), (3, 1));
    }
}
