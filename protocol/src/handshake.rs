//! Version handshake. The host opens with [`crate::HostToCore::Hello`]; a core of the same
//! major version answers [`crate::CoreToHost::HelloAck`], any other answers
//! [`crate::ErrorCode::VersionMismatch`]. Minor versions only add compatible meaning.

use core::fmt;

use crate::error::ErrorCode;
use crate::messages::{Capacities, CoreToHost, HelloAck, ModelKind};
// Defined in `version`, below the messages that carry them; re-exported where they were.
pub use crate::version::{PROTOCOL_VERSION, Version};

/// The core's answer to a `Hello` from a host speaking `host`, from a core that runs `model`
/// as configured by `session` (0 with no configuration).
pub fn answer_hello(
    host: Version,
    model: Option<ModelKind>,
    session: u32,
    capacities: Capacities,
) -> CoreToHost {
    if PROTOCOL_VERSION.compatible_with(host) {
        CoreToHost::HelloAck(HelloAck {
            version: PROTOCOL_VERSION,
            model,
            capacities,
            session,
        })
    } else {
        CoreToHost::error(ErrorCode::VersionMismatch {
            core: PROTOCOL_VERSION,
            host,
        })
    }
}

/// Why the host could not open a session.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HandshakeError {
    /// The core speaks another major version.
    VersionMismatch {
        /// The core's version.
        core: Version,
        /// Ours.
        host: Version,
    },
    /// The core reported an error.
    Refused(ErrorCode),
    /// The core answered something other than `HelloAck` or `Error`.
    Unexpected(&'static str),
}

impl fmt::Display for HandshakeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HandshakeError::VersionMismatch { core, host } => write!(
                f,
                "protocol version mismatch: core speaks {core}, this host speaks {host}; \
                 update the one with the older major version"
            ),
            HandshakeError::Refused(code) => write!(f, "core refused the handshake: {code}"),
            HandshakeError::Unexpected(kind) => {
                write!(f, "core answered Hello with {kind} instead of HelloAck")
            }
        }
    }
}

impl core::error::Error for HandshakeError {}

/// The host's check of the core's answer to its `Hello`.
pub fn check_answer(answer: &CoreToHost) -> Result<HelloAck, HandshakeError> {
    match answer {
        CoreToHost::HelloAck(ack) if PROTOCOL_VERSION.compatible_with(ack.version) => Ok(*ack),
        CoreToHost::HelloAck(ack) => Err(HandshakeError::VersionMismatch {
            core: ack.version,
            host: PROTOCOL_VERSION,
        }),
        CoreToHost::Error(report) => match report.code {
            ErrorCode::VersionMismatch { core, host } => {
                Err(HandshakeError::VersionMismatch { core, host })
            }
            code => Err(HandshakeError::Refused(code)),
        },
        other => Err(HandshakeError::Unexpected(other.kind())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CAPS: Capacities = Capacities {
        max_frame_len: 1034,
        max_correspondences_per_message: 16,
        max_correspondences_per_frame: 64,
        delay_buffer_samples: 32,
        max_pending_frames: 4,
        scalar_bits: 32,
    };

    #[test]
    fn same_major_is_acknowledged() {
        let host = Version {
            major: PROTOCOL_VERSION.major,
            minor: 7,
        };
        let ack = check_answer(&answer_hello(host, None, 0, CAPS)).unwrap();
        assert_eq!(ack.version, PROTOCOL_VERSION);
        assert_eq!(ack.capacities, CAPS);
    }

    #[test]
    fn other_major_gets_a_clear_error() {
        let host = Version {
            major: PROTOCOL_VERSION.major + 1,
            minor: 0,
        };
        let answer = answer_hello(host, Some(ModelKind::Acc), 7, CAPS);
        assert_eq!(
            answer,
            CoreToHost::error(ErrorCode::VersionMismatch {
                core: PROTOCOL_VERSION,
                host
            })
        );
        let err = check_answer(&answer).unwrap_err();
        assert_eq!(
            err,
            HandshakeError::VersionMismatch {
                core: PROTOCOL_VERSION,
                host
            }
        );
    }

    #[test]
    fn host_rejects_an_ack_of_another_major() {
        let ack = CoreToHost::HelloAck(HelloAck {
            version: Version { major: 0, minor: 9 },
            model: None,
            capacities: CAPS,
            session: 0,
        });
        assert!(matches!(
            check_answer(&ack),
            Err(HandshakeError::VersionMismatch { .. })
        ));
    }
}
