//! The host's end of the link to the fusion core: framed messages over any byte transport,
//! with deadlines and the version handshake.

use std::io;
use std::time::{Duration, Instant};

use firmware_sim::transport::Duplex;
use protocol::io::{FrameReader, FrameWriter, RecvError};
use protocol::{CoreToHost, DecodeError, HandshakeError, Hello, HelloAck, HostToCore, Version};

/// Why talking to the core failed.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The transport failed.
    #[error("link {link}: I/O error: {source}")]
    Io {
        /// Link name.
        link: String,
        /// Cause.
        #[source]
        source: io::Error,
    },
    /// The core closed the link.
    #[error("link {link}: closed by the core ({partial} bytes of an unfinished frame lost)")]
    Closed {
        /// Link name.
        link: String,
        /// Bytes of an unfinished frame.
        partial: usize,
    },
    /// A frame from the core was rejected (the link is in sync again).
    #[error("link {link}: {source}")]
    Frame {
        /// Link name.
        link: String,
        /// Why.
        #[source]
        source: DecodeError,
    },
    /// Nothing arrived in time.
    #[error("link {link}: no answer from the core within {waited:?}")]
    Timeout {
        /// Link name.
        link: String,
        /// How long we waited.
        waited: Duration,
    },
    /// The handshake failed.
    #[error("link {link}: {source}")]
    Handshake {
        /// Link name.
        link: String,
        /// Why.
        #[source]
        source: HandshakeError,
    },
}

/// The host's end of a link.
pub struct Link {
    name: String,
    reader: FrameReader<Box<dyn io::Read + Send>>,
    writer: FrameWriter<Box<dyn io::Write + Send>>,
}

impl std::fmt::Debug for Link {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Link").field("name", &self.name).finish()
    }
}

impl Link {
    /// Wraps a transport.
    pub fn new(duplex: Duplex) -> Self {
        Link {
            name: duplex.name,
            reader: FrameReader::new(duplex.reader),
            writer: FrameWriter::new(duplex.writer),
        }
    }

    /// The transport's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Sends one message.
    pub fn send(&mut self, msg: &HostToCore) -> Result<(), LinkError> {
        self.writer.send(msg).map_err(|source| LinkError::Io {
            link: self.name.clone(),
            source,
        })
    }

    /// Writes raw bytes (for fault-injection tests of the core's decoder).
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        let w = self.writer.get_mut();
        w.write_all(bytes)
            .and_then(|_| w.flush())
            .map_err(|source| LinkError::Io {
                link: self.name.clone(),
                source,
            })
    }

    /// Waits up to `timeout` for the next message.
    pub fn recv(&mut self, timeout: Duration) -> Result<CoreToHost, LinkError> {
        let start = Instant::now();
        loop {
            match self.reader.recv::<CoreToHost>() {
                Ok(msg) => return Ok(msg),
                Err(RecvError::Io(e)) if firmware_sim::transport::is_poll_timeout(&e) => {
                    if start.elapsed() >= timeout {
                        return Err(LinkError::Timeout {
                            link: self.name.clone(),
                            waited: start.elapsed(),
                        });
                    }
                }
                Err(RecvError::Io(source)) => {
                    return Err(LinkError::Io {
                        link: self.name.clone(),
                        source,
                    });
                }
                Err(RecvError::Closed { partial }) => {
                    return Err(LinkError::Closed {
                        link: self.name.clone(),
                        partial,
                    });
                }
                Err(RecvError::Frame(source)) => {
                    return Err(LinkError::Frame {
                        link: self.name.clone(),
                        source,
                    });
                }
            }
        }
    }

    /// Opens the session: sends `Hello` with `version` and checks the answer.
    pub fn handshake(
        &mut self,
        version: Version,
        timeout: Duration,
    ) -> Result<HelloAck, LinkError> {
        self.send(&HostToCore::Hello(Hello { version }))?;
        let answer = self.recv(timeout)?;
        protocol::handshake::check_answer(&answer).map_err(|source| LinkError::Handshake {
            link: self.name.clone(),
            source,
        })
    }
}
