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
/// The buffer holds one frame's bytes, COBS-decoded as they arrive (the decoded bytes are
/// never more than the encoded ones, so it is sized for [`MAX_FRAME_LEN`] less its two
/// delimiters). A frame longer than that is dropped
/// up to its delimiter and reported as [`DecodeError::Oversized`]; any other bad frame is
/// reported with its reason. Either way the decoder is in sync again at the next delimiter.
/// Empty frames (two delimiters in a row) are skipped silently: a sender may emit a lone
/// `0x00` to flush a receiver's partial frame.
#[derive(Clone)]
pub struct Decoder {
    buf: [u8; MAX_ENCODED_LEN],
    /// Encoded bytes of the current frame so far.
    len: usize,
    /// Decoded bytes in `buf`.
    out: usize,
    /// Data bytes still due in the current COBS block (0: the next byte is a code byte).
    run: u8,
    /// Whether the current block's code byte implies a zero after it, should another block
    /// follow (every code but `0xFF`).
    zero_after: bool,
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
            out: 0,
            run: 0,
            zero_after: false,
            overflowed: false,
        }
    }

    /// Drops any partial frame.
    pub fn clear(&mut self) {
        self.len = 0;
        self.out = 0;
        self.run = 0;
        self.zero_after = false;
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
        self.advance_raw(bytes, |body| {
            body.and_then(|body| match postcard::take_from_bytes::<T>(body) {
                Ok((msg, [])) => Ok(msg),
                Ok(_) => Err(DecodeError::TrailingBytes),
                Err(_) => Err(DecodeError::Malformed),
            })
        })
    }

    /// [`Self::advance`], but a frame's result is passed by reference to `f`, and what `f`
    /// returns is returned: the decoded message is never moved (a large message type, such
    /// as one holding a vector of correspondences, costs a copy of its whole size per move).
    pub fn advance_with<T: DeserializeOwned, R>(
        &mut self,
        bytes: &[u8],
        f: impl FnOnce(Result<&T, DecodeError>) -> R,
    ) -> (usize, Option<R>) {
        self.advance_raw(bytes, |body| match body {
            Ok(body) => {
                let mut de = postcard::Deserializer::from_bytes(body);
                // Matched by reference: binding the message by value moves it out.
                let msg = T::deserialize(&mut de);
                match &msg {
                    Ok(msg) => match de.finalize() {
                        Ok([]) => f(Ok(msg)),
                        Ok(_) => f(Err(DecodeError::TrailingBytes)),
                        Err(_) => f(Err(DecodeError::Malformed)),
                    },
                    Err(_) => f(Err(DecodeError::Malformed)),
                }
            }
            Err(e) => f(Err(e)),
        })
    }

    /// Consumes bytes up to and including the first delimiter; at the end of a non-empty frame,
    /// passes its CRC-checked postcard body (or why it was rejected) to `f`.
    fn advance_raw<R>(
        &mut self,
        bytes: &[u8],
        f: impl FnOnce(Result<&[u8], DecodeError>) -> R,
    ) -> (usize, Option<R>) {
        let mut consumed = 0;
        loop {
            let (used, ended) = self.append(&bytes[consumed..]);
            consumed += used;
            if !ended {
                return (consumed, None);
            }
            if let Some(body) = self.finish() {
                return (consumed, Some(f(body)));
            }
        }
    }

    /// Feeds one byte; returns a result when it ended a non-empty frame.
    pub fn push<T: DeserializeOwned>(&mut self, byte: u8) -> Option<Result<T, DecodeError>> {
        self.advance(&[byte]).1
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

    /// Adds encoded bytes to the current frame up to and including the first delimiter, if
    /// any, COBS-decoding them into the buffer as they come: a code byte `c` is followed by
    /// `c - 1` data bytes, and then, unless `c` is `0xFF`, by a zero if another block follows.
    /// One pass, a block at a time (frames are short blocks where the data has zeros). Returns
    /// the bytes consumed and whether a delimiter ended the frame. Not inlined: inlined into a
    /// caller with a static decoder (the firmware), its loop rebuilt the buffer's address for
    /// every byte.
    #[inline(never)]
    fn append(&mut self, bytes: &[u8]) -> (usize, bool) {
        let mut out = self.out;
        let mut run = self.run;
        let mut zero_after = self.zero_after;
        let mut used = 0;
        let mut ended = false;
        while let Some(&b) = bytes.get(used) {
            if run == 0 {
                // A code byte (or the delimiter).
                used += 1;
                if b == 0 {
                    ended = true;
                    break;
                }
                if zero_after {
                    // Past the buffer only in a frame that overflows it (and is dropped).
                    if let Some(slot) = self.buf.get_mut(out) {
                        *slot = 0;
                    }
                    out += 1;
                }
                zero_after = b != 0xFF;
                run = b - 1;
            } else {
                // The block's data bytes, up to a delimiter.
                let src = bytes.get(used..).unwrap_or_default();
                let src = src.get(..usize::from(run)).unwrap_or(src);
                let mut copied = 0;
                match self.buf.get_mut(out..out + src.len()) {
                    Some(dst) => {
                        for (d, &s) in dst.iter_mut().zip(src) {
                            if s == 0 {
                                break;
                            }
                            *d = s;
                            copied += 1;
                        }
                    }
                    // A frame overflowing the buffer (dropped): only find its end.
                    None => copied = src.iter().position(|&s| s == 0).unwrap_or(src.len()),
                }
                out += copied;
                used += copied;
                run -= copied as u8;
                if copied < src.len() {
                    used += 1;
                    ended = true;
                    break;
                }
            }
        }
        let body = used - usize::from(ended);
        if !self.overflowed {
            if body > MAX_ENCODED_LEN - self.len {
                self.overflowed = true;
                self.len = 0;
            } else {
                // Decoded bytes never outnumber encoded ones (a zero is written only for a code
                // byte after the first), so `out <= self.len <= MAX_ENCODED_LEN`.
                self.len += body;
                self.out = out;
                self.run = run;
                self.zero_after = zero_after;
            }
        }
        (used, ended)
    }

    /// Ends the current frame at a delimiter: its CRC-checked body, or why it is rejected, or
    /// `None` for an empty frame.
    fn finish(&mut self) -> Option<Result<&[u8], DecodeError>> {
        let len = core::mem::take(&mut self.len);
        let n = core::mem::take(&mut self.out);
        let run = core::mem::take(&mut self.run);
        self.zero_after = false;
        if core::mem::take(&mut self.overflowed) {
            return Some(Err(DecodeError::Oversized));
        }
        if len == 0 {
            return None;
        }
        // A block cut short by the delimiter.
        if run != 0 {
            return Some(Err(DecodeError::Cobs));
        }
        Some(check_crc(self.buf.get(..n).unwrap_or_default()))
    }
}

/// The postcard body of a COBS-decoded frame, if its length and CRC are right.
fn check_crc(decoded: &[u8]) -> Result<&[u8], DecodeError> {
    let n = decoded.len();
    if n < CRC_LEN + 1 {
        return Err(DecodeError::Truncated);
    }
    let (body, crc) = decoded.split_at(n - CRC_LEN);
    let mut crc_bytes = [0u8; CRC_LEN];
    crc_bytes.copy_from_slice(crc);
    if crc32c(body) != u32::from_le_bytes(crc_bytes) {
        return Err(DecodeError::Crc);
    }
    Ok(body)
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

    /// The streaming COBS decode accepts and rejects exactly what `cobs::decode_in_place`
    /// does, with the same bytes, for any split of the input into chunks.
    #[test]
    fn streaming_cobs_decode_matches_the_cobs_crate() {
        let mut x = 0x2545_f491_u32;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        for case in 0..4000 {
            let len = (next() % 700) as usize + 1;
            let frame: Vec<u8> = if case % 2 == 0 {
                // Mostly small codes (block boundaries), some 0xFF codes: mostly invalid.
                (0..len)
                    .map(|_| match next() % 8 {
                        0 => 0xFF,
                        1..=3 => (next() % 6 + 1) as u8,
                        _ => (next() % 255 + 1) as u8,
                    })
                    .collect()
            } else {
                // A valid frame (zeros, long runs), sometimes with one byte changed.
                let mut raw: Vec<u8> = (0..len)
                    .map(|_| if next() % 4 == 0 { 0 } else { next() as u8 | 1 })
                    .collect();
                if case % 6 == 1 {
                    raw.iter_mut().for_each(|b| *b |= 1);
                }
                raw.extend(crc32c(&raw).to_le_bytes());
                let mut enc = vec![0u8; cobs::max_encoding_length(raw.len())];
                let n = cobs::encode(&raw, &mut enc);
                enc.truncate(n);
                if case % 3 == 0 {
                    let i = next() as usize % n;
                    enc[i] = (next() % 255 + 1) as u8;
                }
                enc
            };
            let mut expect = frame.clone();
            let expect = match cobs::decode_in_place(&mut expect) {
                Err(_) => Err(DecodeError::Cobs),
                Ok(n) => check_crc(&expect[..n]).map(|b| b.to_vec()),
            };
            let chunk = (next() % 64) as usize + 1;
            let mut dec = Decoder::new();
            let mut got = None;
            let mut stream = frame.clone();
            stream.push(0);
            for piece in stream.chunks(chunk) {
                let (used, r) = dec.advance_raw(piece, |b| b.map(|b| b.to_vec()));
                assert_eq!(used, piece.len());
                if r.is_some() {
                    got = r;
                }
            }
            assert_eq!(got, Some(expect), "case {case}");
        }
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
