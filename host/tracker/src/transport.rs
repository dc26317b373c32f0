//! The core behind the tracker: a [`CoreTransport`] carries the wire protocol's messages
//! (protocol/PROTOCOL.md) to a fusion core and its answers back. [`crate::InProcessCore`]
//! implements it for the core called in-process; the `core-link` crate's `CoreLink` for the
//! links to a board (the simulated board on a pty pair or called in-process, a serial or TCP
//! board, the firmware under QEMU); a program with a link of its own implements it too.

use std::time::Duration;

use protocol::{CoreToHost, DecodeError, HostToCore};

use crate::error::TrackerError;

/// What the reader thread passes on.
#[derive(Debug, Clone)]
pub enum Incoming {
    /// A message from the core.
    Message(CoreToHost),
    /// A frame from the core that failed to decode (the reader is in sync again).
    Rejected(DecodeError),
}

/// A fusion core at the other end of a link.
pub trait CoreTransport {
    /// The link's name, for messages.
    fn name(&self) -> &str;

    /// Sends one message. A link that is down fails with [`TrackerError::Link`].
    fn send(&mut self, msg: &HostToCore) -> Result<(), TrackerError>;

    /// Waits up to `timeout` for the next item from the core; `None` if none came.
    fn recv_within(&mut self, timeout: Duration) -> Result<Option<Incoming>, TrackerError>;

    /// The next item if one is waiting.
    fn try_recv(&mut self) -> Result<Option<Incoming>, TrackerError> {
        self.recv_within(Duration::ZERO)
    }

    /// Waits up to `timeout` for the next item; no answer in time is a
    /// [`TrackerError::Link`].
    fn recv(&mut self, timeout: Duration) -> Result<Incoming, TrackerError> {
        self.recv_within(timeout)?.ok_or_else(|| {
            TrackerError::Link(format!(
                "link {}: no answer from the core within {timeout:?}",
                self.name()
            ))
        })
    }

    /// Opens the link again after it was lost.
    fn reconnect(&mut self) -> Result<(), TrackerError>;

    /// Whether a connection is open (the next exchange needs no [`Self::reconnect`]).
    fn is_connected(&self) -> bool {
        true
    }

    /// Drops the connection after a failed exchange, so that the next attempt starts over
    /// with [`Self::reconnect`].
    fn disconnect(&mut self) {}

    /// Whether messages may be lost on the way (a line with bit errors): a `Hello` unanswered
    /// is then sent again, and a `Configure` or `Init` until it is confirmed.
    fn lossy(&self) -> bool {
        false
    }
}
