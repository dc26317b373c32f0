//! Blocking framed I/O over `std::io` byte streams (feature `std`): serial ports, ptys, pipes,
//! TCP sockets.

use std::boxed::Box;
use std::io::{self, Read, Write};

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::decoder::Decoder;
use crate::error::{DecodeError, EncodeError};
use crate::framing::encode_frame;
use crate::limits::MAX_FRAME_LEN;

/// Writes messages as frames.
#[derive(Debug)]
pub struct FrameWriter<W> {
    inner: W,
    buf: Box<[u8; MAX_FRAME_LEN]>,
}

impl<W: Write> FrameWriter<W> {
    /// Wraps a byte sink.
    pub fn new(inner: W) -> Self {
        FrameWriter {
            inner,
            buf: Box::new([0; MAX_FRAME_LEN]),
        }
    }

    /// Encodes and writes one message, then flushes.
    pub fn send<T: Serialize>(&mut self, msg: &T) -> io::Result<()> {
        let frame = encode_frame(msg, &mut self.buf[..])
            .map_err(|e: EncodeError| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        self.inner.write_all(frame)?;
        self.inner.flush()
    }

    /// The wrapped sink.
    pub fn get_mut(&mut self) -> &mut W {
        &mut self.inner
    }

    /// Unwraps the sink.
    pub fn into_inner(self) -> W {
        self.inner
    }
}

/// Why [`FrameReader::recv`] returned without a message.
#[derive(Debug)]
pub enum RecvError {
    /// The byte stream failed (a timeout is `io::ErrorKind::TimedOut` or `WouldBlock`).
    Io(io::Error),
    /// The stream ended; `partial` bytes of an unfinished frame were pending.
    Closed {
        /// Bytes of an unfinished frame that were lost.
        partial: usize,
    },
    /// A frame was rejected; the reader is in sync again and the next `recv` goes on.
    Frame(DecodeError),
}

impl core::fmt::Display for RecvError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RecvError::Io(e) => write!(f, "link I/O error: {e}"),
            RecvError::Closed { partial: 0 } => f.write_str("link closed by the peer"),
            RecvError::Closed { partial } => {
                write!(
                    f,
                    "link closed by the peer in the middle of a frame ({partial} bytes lost)"
                )
            }
            RecvError::Frame(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for RecvError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            RecvError::Io(e) => Some(e),
            RecvError::Frame(e) => Some(e),
            RecvError::Closed { .. } => None,
        }
    }
}

/// Reads frames from a byte stream and decodes them into messages.
pub struct FrameReader<R> {
    inner: R,
    decoder: Box<Decoder>,
    chunk: Box<[u8; 4096]>,
    start: usize,
    end: usize,
}

impl<R> core::fmt::Debug for FrameReader<R> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("FrameReader")
            .field("decoder", &self.decoder)
            .field("buffered", &(self.end - self.start))
            .finish()
    }
}

impl<R: Read> FrameReader<R> {
    /// Wraps a byte source.
    pub fn new(inner: R) -> Self {
        FrameReader {
            inner,
            decoder: Box::new(Decoder::new()),
            chunk: Box::new([0; 4096]),
            start: 0,
            end: 0,
        }
    }

    /// Blocks until the next frame ends, then returns its message or why it was rejected.
    pub fn recv<T: DeserializeOwned>(&mut self) -> Result<T, RecvError> {
        loop {
            if self.start < self.end {
                let (used, result) = self.decoder.advance(&self.chunk[self.start..self.end]);
                self.start += used;
                if let Some(result) = result {
                    return result.map_err(RecvError::Frame);
                }
            }
            match self.inner.read(&mut self.chunk[..]) {
                Ok(0) => {
                    return Err(RecvError::Closed {
                        partial: self.decoder.pending(),
                    });
                }
                Ok(n) => {
                    self.start = 0;
                    self.end = n;
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(RecvError::Io(e)),
            }
        }
    }

    /// The wrapped source (for example to set a timeout).
    pub fn get_mut(&mut self) -> &mut R {
        &mut self.inner
    }
}

#[cfg(test)]
mod tests {
    use std::vec::Vec;

    use super::*;
    use crate::{CoreToHost, ErrorCode, HostToCore};

    /// A reader that hands out one byte per call, to exercise partial reads.
    struct Trickle(Vec<u8>, usize);

    impl Read for Trickle {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            if self.1 >= self.0.len() || buf.is_empty() {
                return Ok(0);
            }
            buf[0] = self.0[self.1];
            self.1 += 1;
            Ok(1)
        }
    }

    #[test]
    fn writer_and_reader_round_trip_over_partial_reads() {
        let mut w = FrameWriter::new(Vec::new());
        w.send(&HostToCore::Reset).unwrap();
        w.send(&CoreToHost::error(ErrorCode::NotConfigured))
            .unwrap();
        let bytes = w.into_inner();
        // Mixing directions on one stream is a caller error; here each is read as its own type.
        let mut r = FrameReader::new(Trickle(bytes, 0));
        assert_eq!(r.recv::<HostToCore>().unwrap(), HostToCore::Reset);
        assert_eq!(
            r.recv::<CoreToHost>().unwrap(),
            CoreToHost::error(ErrorCode::NotConfigured)
        );
        assert!(matches!(
            r.recv::<HostToCore>(),
            Err(RecvError::Closed { partial: 0 })
        ));
    }

    #[test]
    fn close_in_the_middle_of_a_frame_reports_lost_bytes() {
        let mut w = FrameWriter::new(Vec::new());
        w.send(&HostToCore::Reset).unwrap();
        let mut bytes = w.into_inner();
        bytes.pop(); // drop the closing delimiter
        let n = bytes.len() - 1; // all but the opening delimiter are pending
        let mut r = FrameReader::new(&bytes[..]);
        match r.recv::<HostToCore>() {
            Err(RecvError::Closed { partial }) => assert_eq!(partial, n),
            other => panic!("expected Closed, got {other:?}"),
        }
    }
}
