//! The fusion core called in-process: [`fusion_core::Device`] behind [`CoreTransport`], each
//! message handled when it is sent and its answers queued for the tracker. No link, no thread,
//! no bytes: a run is deterministic, and a program embedding the tracker needs nothing else.
//! The answers are the messages a board would send (the wire's encoding of a float is exact).

use std::collections::VecDeque;
use std::time::Duration;

use fusion_core::{Device, Precision};
use protocol::HostToCore;

use crate::error::TrackerError;
use crate::transport::{CoreTransport, Incoming};

/// The core in this process, of either width.
pub struct InProcessCore {
    device: Width,
    answers: VecDeque<Incoming>,
    name: &'static str,
}

/// The device, on the heap: the f64 device is 26 KB.
enum Width {
    F32(Box<Device<f32>>),
    F64(Box<Device<f64>>),
}

impl InProcessCore {
    /// A core just started, with `f32` (as on the Cortex-M4F) or `f64` arithmetic.
    pub fn new(precision: Precision) -> Self {
        let (device, name) = match precision {
            Precision::F32 => (
                Width::F32(Box::default()),
                "inproc (f32 core called directly in this process)",
            ),
            Precision::F64 => (
                Width::F64(Box::default()),
                "inproc:f64 (f64 core called directly in this process)",
            ),
        };
        Self {
            device,
            answers: VecDeque::new(),
            name,
        }
    }
}

impl Default for InProcessCore {
    /// The `f32` core, the board's.
    fn default() -> Self {
        Self::new(Precision::F32)
    }
}

impl std::fmt::Debug for InProcessCore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("InProcessCore")
            .field("name", &self.name)
            .field("answers_waiting", &self.answers.len())
            .finish()
    }
}

impl CoreTransport for InProcessCore {
    fn name(&self) -> &str {
        self.name
    }

    fn send(&mut self, msg: &HostToCore) -> Result<(), TrackerError> {
        let answers = &mut self.answers;
        let mut out = |m| answers.push_back(Incoming::Message(m));
        match &mut self.device {
            Width::F32(d) => d.handle(msg, &mut out),
            Width::F64(d) => d.handle(msg, &mut out),
        }
        Ok(())
    }

    fn recv_within(&mut self, _timeout: Duration) -> Result<Option<Incoming>, TrackerError> {
        // The core answered when it was called: what is not here will not come.
        Ok(self.answers.pop_front())
    }

    fn reconnect(&mut self) -> Result<(), TrackerError> {
        // A new session on the same core: its host shakes hands again.
        match &mut self.device {
            Width::F32(d) => d.link_opened(),
            Width::F64(d) => d.link_opened(),
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{CoreToHost, Hello, PROTOCOL_VERSION};

    #[test]
    fn answers_a_hello_at_once_and_nothing_more() {
        for precision in [Precision::F32, Precision::F64] {
            let mut core = InProcessCore::new(precision);
            core.send(&HostToCore::Hello(Hello {
                version: PROTOCOL_VERSION,
            }))
            .unwrap();
            let answer = core.try_recv().unwrap();
            assert!(
                matches!(answer, Some(Incoming::Message(CoreToHost::HelloAck(_)))),
                "{answer:?}"
            );
            assert!(core.try_recv().unwrap().is_none());
        }
    }
}
