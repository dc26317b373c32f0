//! Wire protocol between the embedded fusion core and the vision host.
//!
//! This crate is the only contract between the two ends (docs/ARCHITECTURE.md §5). It holds:
//!
//! - the message types ([`HostToCore`], [`CoreToHost`]) as serde types encoded with postcard;
//! - the framing ([`encode_frame`]): postcard body, CRC-32C, COBS, `0x00` delimiter;
//! - a streaming [`Decoder`] with a fixed buffer that takes bytes in arbitrary chunks,
//!   rejects corrupted or oversized frames with a typed [`DecodeError`] and resynchronises on
//!   the next delimiter;
//! - field validation of incoming messages ([`HostToCore::validate`]);
//! - the protocol version ([`version`]) and the handshake ([`handshake`]);
//! - every size bound as an exported constant ([`limits`]).
//!
//! It is `no_std` and never allocates. With the `std` feature, [`io`] adds blocking framed
//! reader and writer adaptors for `std::io` byte streams (serial ports, pipes, sockets).
//!
//! `PROTOCOL.md` next to this crate documents every message, unit and byte.
#![no_std]
#![deny(missing_docs)]

#[cfg(feature = "std")]
extern crate std;

pub mod decoder;
pub mod error;
pub mod framing;
pub mod handshake;
#[cfg(feature = "std")]
pub mod io;
pub mod limits;
pub mod messages;
pub mod samples;
pub mod validate;
pub mod version;

pub use decoder::{Decoder, Frames};
pub use error::{DecodeError, EncodeError, ErrorCode, InvalidField};
pub use framing::{body_len, crc32c, encode_frame};
pub use handshake::HandshakeError;
pub use limits::*;
pub use messages::*;
pub use version::{PROTOCOL_VERSION, Version};
