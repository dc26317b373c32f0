//! Streaming frame decoder with a fixed buffer.

use core::marker::PhantomData;

use serde::de::DeserializeOwned;

use crate::error::DecodeError;
use crate::framing::crc32c;
use crate::limits::{CRC_LEN, MAX_FRAME_LEN};

/// Most encoded bytes between two delimiters.
const MAX_ENCODED_LEN: usize = MAX_FRAME_LEN - 2;

/// Accumulates bytes, in chunks of any size, into frames and decodes them.
///
/// The buffer holds the encoded bytes of one frame ([`MAX_FRAME_LEN`] less its two
/// delimiters). A frame longer than that is dropped
/// up to its delimiter and reported as [`DecodeError::Oversized`]; any other bad frame is
/// reported with its reason. Either way the decoder is in sync again at the next delimiter.
/// Empty frames (two delimiters in a row) are skipped silently: a sender may emit a lone
/// `0x00` to flush a receiver's partial frame.
#[derive(Clone)]
pub struct Decoder {
    buf: [u8; MAX_ENCODED_LEN],
    len: usize,
    overflowed: bool,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl core::fmt::Debug for Decoder {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Decoder")
            .field("pending", &self.len)
            .field("overflowed", &self.overflowed)
            .finish()
    }
}

impl Decoder {
    /// An empty decoder.
    pub const fn new() -> Self {
        Decoder {
            buf: [0; MAX_ENCODED_LEN],
            len: 0,
            overflowed: false,
        }
    }

    /// Drops any partial frame.
    pub fn clear(&mut self) {
        self.len = 0;
        self.overflowed = false;
    }

    /// Bytes of an unfinished frame held so far.
    pub fn pending(&self) -> usize {
        self.len
    }

    /// Consumes bytes from `bytes` up to and including the first delimiter, if any.
    ///
    /// Returns how many bytes were consumed and, if a frame ended, its result. Call again with
    /// the rest of the input until it is consumed. Empty frames are consumed without a result.
    pub fn advance<T: DeserializeOwned>(
        &mut self,
        bytes: &[u8],
    ) -> (usize, Option<Result<T, DecodeError>>) {
        let mut consumed = 0;
        loop {
            let rest = &bytes[consumed..];
            let (body, ended) = match rest.iter().position(|&b| b == 0) {
                Some(i) => (&rest[..i], true),
                None => (rest, false),
            };
            self.append(body);
            consumed += body.len();
            if !ended {
                return (consumed, None);
            }
            consumed += 1; // the delimiter
            if let Some(result) = self.finish() {
                return (consumed, Some(result));
            }
        }
    }

    /// Feeds one byte; returns a result when it ended a non-empty frame.
    pub fn push<T: DeserializeOwned>(&mut self, byte: u8) -> Option<Result<T, DecodeError>> {
        if byte == 0 {
            self.finish()
        } else {
            self.append(&[byte]);
            None
        }
    }

    /// Iterates over the results of the frames that `bytes` completes. Bytes after the last
    /// delimiter stay buffered for the next call.
    pub fn feed<'d, 'b, T: DeserializeOwned>(&'d mut self, bytes: &'b [u8]) -> Frames<'d, 'b, T> {
        Frames {
            decoder: self,
            rest: bytes,
            _msg: PhantomData,
        }
    }

    fn append(&mut self, body: &[u8]) {
        if self.overflowed {
            return;
        }
        let room = MAX_ENCODED_LEN - self.len;
        if body.len() > room {
            self.overflowed = true;
            self.len = 0;
        } else {
            self.buf[self.len..self.len + body.len()].copy_from_slice(body);
            self.len += body.len();
        }
    }

    /// Ends the current frame at a delimiter.
    fn finish<T: DeserializeOwned>(&mut self) -> Option<Result<T, DecodeError>> {
        let len = core::mem::take(&mut self.len);
        if core::mem::take(&mut self.overflowed) {
            return Some(Err(DecodeError::Oversized));
        }
        if len == 0 {
            return None;
        }
        Some(decode_frame(&mut self.buf[..len]))
    }
}

/// Decodes one COBS frame without its delimiter, in place.
fn decode_frame<T: DeserializeOwned>(encoded: &mut [u8]) -> Result<T, DecodeError> {
    let n = cobs::decode_in_place(encoded).map_err(|_| DecodeError::Cobs)?;
    if n < CRC_LEN + 1 {
        return Err(DecodeError::Truncated);
    }
    let (body, crc) = encoded[..n].split_at(n - CRC_LEN);
    let mut crc_bytes = [0u8; CRC_LEN];
    crc_bytes.copy_from_slice(crc);
    if crc32c(body) != u32::from_le_bytes(crc_bytes) {
        return Err(DecodeError::Crc);
    }
    match postcard::take_from_bytes::<T>(body) {
        Ok((msg, [])) => Ok(msg),
        Ok(_) => Err(DecodeError::TrailingBytes),
        Err(_) => Err(DecodeError::Malformed),
    }
}

/// Iterator over the frames completed by one chunk of input (see [`Decoder::feed`]).
pub struct Frames<'d, 'b, T> {
    decoder: &'d mut Decoder,
    rest: &'b [u8],
    _msg: PhantomData<fn() -> T>,
}

impl<T> Frames<'_, '_, T> {
    /// Input not yet consumed (empty once the iterator has returned `None`).
    pub fn remaining(&self) -> usize {
        self.rest.len()
    }
}

impl<T: DeserializeOwned> Iterator for Frames<'_, '_, T> {
    type Item = Result<T, DecodeError>;

    fn next(&mut self) -> Option<Self::Item> {
        let (used, result) = self.decoder.advance(self.rest);
        self.rest = &self.rest[used..];
        result
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::vec;
    use std::vec::Vec;

    use super::*;
    use crate::{HostToCore, ImuSample, encode_frame};

    fn imu(t_us: u64) -> HostToCore {
        HostToCore::Imu(ImuSample {
            t_us,
            gyro: [0.1, -0.2, 0.3],
            accel: [0.0, 0.0, 9.81],
            trigger: t_us.is_multiple_of(4),
        })
    }

    fn frame(msg: &HostToCore) -> Vec<u8> {
        let mut out = [0u8; MAX_FRAME_LEN];
        encode_frame(msg, &mut out).unwrap().to_vec()
    }

    #[test]
    fn decodes_back_to_back_frames_and_skips_empty_ones() {
        let mut stream = vec![0u8, 0];
        for t in 0..5 {
            stream.extend(frame(&imu(t)));
            stream.push(0);
        }
        let mut dec = Decoder::new();
        let got: Vec<_> = dec.feed::<HostToCore>(&stream).collect();
        assert_eq!(got, (0..5).map(|t| Ok(imu(t))).collect::<Vec<_>>());
        assert_eq!(dec.pending(), 0);
    }

    #[test]
    fn oversized_frame_is_reported_once_then_resyncs() {
        let mut stream = vec![0x55u8; MAX_FRAME_LEN * 3];
        stream.push(0);
        stream.extend(frame(&imu(1)));
        let mut dec = Decoder::new();
        let got: Vec<_> = dec.feed::<HostToCore>(&stream).collect();
        assert_eq!(got, vec![Err(DecodeError::Oversized), Ok(imu(1))]);
    }

    #[test]
    fn largest_legal_encoded_length_is_accepted_by_the_buffer() {
        // MAX_ENCODED_LEN non-zero bytes fit (they fail later checks, but not as Oversized).
        let mut dec = Decoder::new();
        let mut stream = vec![0x01u8; MAX_ENCODED_LEN];
        stream.push(0);
        let got: Vec<_> = dec.feed::<HostToCore>(&stream).collect();
        assert_eq!(got.len(), 1);
        assert_ne!(got[0], Err(DecodeError::Oversized));
        let mut stream = vec![0x01u8; MAX_ENCODED_LEN + 1];
        stream.push(0);
        let got: Vec<_> = dec.feed::<HostToCore>(&stream).collect();
        assert_eq!(got, vec![Err(DecodeError::Oversized)]);
    }

    #[test]
    fn push_and_feed_agree() {
        let stream: Vec<u8> = (0..3).flat_map(|t| frame(&imu(t))).collect();
        let mut dec = Decoder::new();
        let by_byte: Vec<_> = stream
            .iter()
            .filter_map(|&b| dec.push::<HostToCore>(b))
            .collect();
        let mut dec = Decoder::new();
        let by_chunk: Vec<_> = dec.feed::<HostToCore>(&stream).collect();
        assert_eq!(by_byte, by_chunk);
    }

    #[test]
    fn short_frames_are_truncated_not_panics() {
        let mut dec = Decoder::new();
        for len in 1..=5 {
            let mut stream = vec![0x01u8; len];
            stream.push(0);
            let got: Vec<_> = dec.feed::<HostToCore>(&stream).collect();
            assert_eq!(got.len(), 1, "len {len}");
            assert!(got[0].is_err());
        }
    }
}
