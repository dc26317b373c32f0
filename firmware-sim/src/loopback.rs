//! The board end of the loop-back self-test: a peer that speaks the protocol's framing and
//! handshake exactly as the core will, and records what it received so that the host can check
//! every byte crossed the link intact. It runs no filter.

use std::io;

use protocol::io::{FrameReader, FrameWriter, RecvError};
use protocol::{CoreToHost, ErrorCode, HostToCore, handshake, samples};

use crate::transport::{self, Duplex};

/// Capacities the loop-back peer announces (those of the protocol itself).
pub const CAPACITIES: protocol::Capacities = protocol::Capacities {
    max_frame_len: protocol::MAX_FRAME_LEN as u16,
    max_correspondences_per_message: protocol::MAX_CORRESPONDENCES_PER_MESSAGE as u16,
    max_correspondences_per_frame: protocol::MAX_CORRESPONDENCES_PER_FRAME as u16,
    delay_buffer_samples: 0,
    max_pending_frames: 0,
    scalar_bits: 64,
};

/// What the peer saw.
#[derive(Debug, Default)]
pub struct PeerLog {
    /// Every valid message received, in order.
    pub received: Vec<HostToCore>,
    /// Every rejected frame, in order.
    pub rejected: Vec<protocol::DecodeError>,
}

/// Serves one session until the host closes the link.
///
/// - `Hello`: answered by the handshake ([`handshake::answer_hello`]);
/// - a rejected frame: answered with `Error(Decode)`, as the core does;
/// - a message failing validation: answered with `Error(Invalid)`;
/// - `Reset`: answered with one sample of every core message ([`samples::core_messages`]);
/// - everything else: recorded.
pub fn serve(link: Duplex) -> io::Result<PeerLog> {
    let mut reader = FrameReader::new(link.reader);
    let mut writer = FrameWriter::new(link.writer);
    let mut log = PeerLog::default();
    loop {
        let msg = match reader.recv::<HostToCore>() {
            Ok(msg) => msg,
            Err(RecvError::Frame(e)) => {
                log.rejected.push(e);
                writer.send(&CoreToHost::error(ErrorCode::Decode(e)))?;
                continue;
            }
            Err(RecvError::Io(e)) if transport::is_poll_timeout(&e) => continue,
            Err(RecvError::Io(e)) => return Err(e),
            Err(RecvError::Closed { .. }) => return Ok(log),
        };
        if let Err(field) = msg.validate() {
            writer.send(&CoreToHost::error(ErrorCode::Invalid(field)))?;
            continue;
        }
        match &msg {
            HostToCore::Hello(hello) => {
                writer.send(&handshake::answer_hello(hello.version, None, 0, CAPACITIES))?;
            }
            HostToCore::Reset => {
                for (_, reply) in samples::core_messages() {
                    writer.send(&reply)?;
                }
            }
            _ => {}
        }
        log.received.push(msg);
    }
}
