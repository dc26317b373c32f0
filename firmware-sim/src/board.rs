//! The simulated board: `fusion-core`'s device loop ([`DeviceIo`]) behind a byte transport,
//! exactly as the firmware runs it behind its UART.
//!
//! The board only reacts to bytes: pacing is the host's. In lock-step replay the host streams
//! recorded IMU samples as fast as the link takes them and holds each frame's correspondences
//! for a simulated latency; in real time it paces the samples by the clock. Either way the
//! board's answers depend only on the bytes it received, so a replay is deterministic.

use std::io::{self, Read as _, Write as _};
use std::thread::JoinHandle;

use fusion_core::device::{Counters, DeviceIo};
use fusion_core::kernels::Kernels;

use crate::transport::{self, Duplex};

/// Floating-point width of the simulated core.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Precision {
    /// `f32`, as on the Cortex-M4F.
    F32,
    /// `f64`, the PC reference.
    F64,
}

/// What the board did in one session.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoardReport {
    /// Bytes received.
    pub bytes_in: u64,
    /// Bytes sent.
    pub bytes_out: u64,
    /// The device's counters at the end.
    pub counters: Counters,
}

/// Serves one session on `link` until the host closes it.
///
/// Returns the report on a clean end of stream; a transport error ends the session with that
/// error.
pub fn serve(link: Duplex, precision: Precision) -> io::Result<BoardReport> {
    match precision {
        Precision::F32 => serve_with::<f32>(link),
        Precision::F64 => serve_with::<f64>(link),
    }
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

fn serve_with<T: Kernels>(link: Duplex) -> io::Result<BoardReport> {
    // On the heap: the f64 device is 26 KB.
    let mut io = Box::<DeviceIo<T>>::default();
    let Duplex {
        mut reader,
        mut writer,
        ..
    } = link;
    let mut buf = [0u8; 4096];
    let mut out = Vec::with_capacity(4096);
    let (mut bytes_in, mut bytes_out) = (0u64, 0u64);
    loop {
        let n = match reader.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if transport::is_poll_timeout(&e) => continue,
            // The host hung up.
            Err(e) if transport::is_hang_up(&e) => break,
            Err(e) => return Err(e),
        };
        bytes_in += n as u64;
        out.clear();
        io.receive(&buf[..n], &mut |frame| out.extend_from_slice(frame));
        if !out.is_empty() {
            match writer.write_all(&out).and_then(|_| writer.flush()) {
                Ok(()) => bytes_out += out.len() as u64,
                // The host hung up while answers were in flight.
                Err(e) if transport::is_hang_up(&e) => break,
                Err(e) => return Err(e),
            }
        }
    }
    Ok(BoardReport {
        bytes_in,
        bytes_out,
        counters: *io.device.counters(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::pty_pair;
    use protocol::io::{FrameReader, FrameWriter};
    use protocol::{CoreToHost, Hello, HostToCore, Mode, PROTOCOL_VERSION};

    #[test]
    fn answers_over_a_pty_and_ends_with_the_session() {
        let (host, board) = pty_pair().unwrap();
        let handle = spawn(board, Precision::F32).unwrap();
        let mut w = FrameWriter::new(host.writer);
        let mut r = FrameReader::new(host.reader);
        let mut recv = || loop {
            match r.recv::<CoreToHost>() {
                Ok(m) => return m,
                Err(protocol::io::RecvError::Io(e)) if transport::is_poll_timeout(&e) => {}
                Err(e) => panic!("{e:?}"),
            }
        };
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
}
