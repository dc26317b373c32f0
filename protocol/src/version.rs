//! Protocol versions: what a peer announces in the handshake ([`crate::handshake`]) and what a
//! version mismatch reports ([`crate::ErrorCode::VersionMismatch`]).

use core::fmt;

use serde::{Deserialize, Serialize};

/// A protocol version. Its layout (two `u16`) never changes.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Version {
    /// Incompatible changes increment this.
    pub major: u16,
    /// Compatible changes increment this.
    pub minor: u16,
}

impl fmt::Display for Version {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}", self.major, self.minor)
    }
}

impl Version {
    /// Whether two peers of these versions can talk.
    pub const fn compatible_with(self, other: Version) -> bool {
        self.major == other.major
    }
}

/// The version this crate implements.
pub const PROTOCOL_VERSION: Version = Version { major: 4, minor: 0 };
