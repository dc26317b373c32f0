//! Framing: `0x00 ‖ COBS(postcard(msg) ‖ CRC-32C(postcard(msg)) as little-endian u32) ‖ 0x00`.
//!
//! COBS removes every zero byte from the frame, so `0x00` marks frame boundaries unambiguously
//! and a receiver that lost sync finds the next frame at the next zero. Each frame is delimited
//! on both sides: if a frame's closing delimiter is corrupted, the next frame's opening one
//! still ends the damage there, so only the corrupted frame is lost. (The receiver skips the
//! empty frame between two delimiters.) The CRC-32C (Castagnoli,
//! reflected, init and xor-out `0xFFFFFFFF`, check value `0xE3069283`) detects corruption.

use serde::Serialize;

use crate::error::EncodeError;
use crate::limits::{CRC_LEN, MAX_FRAME_LEN, MAX_PAYLOAD_LEN};

/// CRC-32C's byte table (reflected polynomial `0x82F63B78`).
const CRC_TABLE: [u32; 256] = {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 {
                (c >> 1) ^ 0x82F6_3B78
            } else {
                c >> 1
            };
            k += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
};

/// CRC-32C of `bytes`: the byte-wise table algorithm, reading four bytes at a time (each
/// word is xored into the CRC at once; then four table steps), which on the MCU is about half
/// the instructions per byte of the byte loop.
pub fn crc32c(bytes: &[u8]) -> u32 {
    let step = |c: u32| CRC_TABLE[(c & 0xFF) as usize] ^ (c >> 8);
    let mut crc = !0u32;
    let mut words = bytes.chunks_exact(4);
    for w in &mut words {
        crc ^= u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
        crc = step(step(step(step(crc))));
    }
    for &b in words.remainder() {
        crc = step(crc ^ u32::from(b));
    }
    !crc
}

/// Length of `msg`'s postcard body (without CRC, COBS and delimiter).
pub fn body_len<T: Serialize>(msg: &T) -> Result<usize, EncodeError> {
    postcard::experimental::serialized_size(msg).map_err(|_| EncodeError::PayloadTooLarge)
}

/// Encodes `msg` as one complete frame (both delimiters included) into `out` and returns the frame.
/// `out` of [`crate::MAX_FRAME_LEN`] bytes always suffices for the protocol's messages.
pub fn encode_frame<'o, T: Serialize>(msg: &T, out: &'o mut [u8]) -> Result<&'o [u8], EncodeError> {
    if out.len() >= MAX_FRAME_LEN {
        encode_in_place(msg, out)
    } else {
        encode_via_copy(msg, out)
    }
}

/// Where [`encode_in_place`] serialises the body: after the opening delimiter and the first
/// COBS code byte.
const BODY_AT: usize = 2;
/// Room for the body, its CRC, one inserted code byte per 254 data bytes after the first block
/// and the closing delimiter.
const _: () = assert!(
    BODY_AT + MAX_PAYLOAD_LEN + CRC_LEN + (MAX_PAYLOAD_LEN + CRC_LEN - 1) / 254 < MAX_FRAME_LEN
);

/// [`encode_frame`] into a buffer of at least [`MAX_FRAME_LEN`] bytes: the body and its CRC
/// are written at [`BODY_AT`] and COBS-encoded in place (no second buffer to zero and copy).
/// The same bytes as [`encode_via_copy`].
fn encode_in_place<'o, T: Serialize>(msg: &T, out: &'o mut [u8]) -> Result<&'o [u8], EncodeError> {
    let body_len = postcard::to_slice(msg, &mut out[BODY_AT..BODY_AT + MAX_PAYLOAD_LEN])
        .map_err(|_| EncodeError::PayloadTooLarge)?
        .len();
    let crc = crc32c(&out[BODY_AT..BODY_AT + body_len]);
    let mut end = BODY_AT + body_len + CRC_LEN;
    out[BODY_AT + body_len..end].copy_from_slice(&crc.to_le_bytes());
    // COBS: each block is a code byte (1 + its data bytes) and up to 254 non-zero bytes; a zero
    // ends a block, and so does the 254th data byte (code 0xFF, no zero implied). With the
    // body one byte after the first code byte, every zero is where the next block's code byte
    // goes: nothing moves, except after a full block without a zero (only in bodies of more
    // than 254 bytes), where the rest shifts by one for the inserted code byte.
    out[0] = 0;
    let mut code_at = BODY_AT - 1;
    loop {
        let start = code_at + 1;
        let limit = (end - start).min(254);
        match out[start..start + limit].iter().position(|&b| b == 0) {
            Some(k) => {
                // The zero is implied by the block; an empty block follows a final zero.
                out[code_at] = k as u8 + 1;
                code_at = start + k;
            }
            None => {
                out[code_at] = limit as u8 + 1;
                code_at = start + limit;
                if limit < 254 || code_at == end {
                    break;
                }
                // A byte loop, not `copy_within`: the device image then needs no `memmove`
                // (1.6 KB of flash, issue 18) for this rare path.
                let mut i = end;
                while i > code_at {
                    out[i] = out[i - 1];
                    i -= 1;
                }
                end += 1;
            }
        }
    }
    out[end] = 0;
    Ok(&out[..end + 1])
}

/// [`encode_frame`] into any buffer, through a body buffer on the stack.
fn encode_via_copy<'o, T: Serialize>(msg: &T, out: &'o mut [u8]) -> Result<&'o [u8], EncodeError> {
    let mut raw = [0u8; MAX_PAYLOAD_LEN + CRC_LEN];
    let body_len = postcard::to_slice(msg, &mut raw[..MAX_PAYLOAD_LEN])
        .map_err(|_| EncodeError::PayloadTooLarge)?
        .len();
    let crc = crc32c(&raw[..body_len]);
    raw[body_len..body_len + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
    let raw = &raw[..body_len + CRC_LEN];

    // Room for the two delimiters around the COBS output.
    let cobs_end = out
        .len()
        .checked_sub(1)
        .ok_or(EncodeError::BufferTooSmall)?;
    if cobs_end < 1 {
        return Err(EncodeError::BufferTooSmall);
    }
    out[0] = 0;
    let n =
        cobs::try_encode(raw, &mut out[1..cobs_end]).map_err(|_| EncodeError::BufferTooSmall)?;
    out[1 + n] = 0;
    Ok(&out[..n + 2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_check_value() {
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
    }

    /// The same CRC as the `crc` crate's CRC-32/ISCSI, for every length and alignment.
    #[test]
    fn crc32c_matches_the_crc_crate() {
        const REF: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);
        let data: [u8; 600] = core::array::from_fn(|i| (i * 7919 % 251) as u8 ^ (i >> 3) as u8);
        for start in 0..4 {
            for len in 0..data.len() - start {
                let b = &data[start..start + len];
                assert_eq!(crc32c(b), REF.checksum(b), "start {start}, len {len}");
            }
        }
    }

    #[test]
    fn small_buffers_are_an_error_not_a_panic() {
        let msg = crate::HostToCore::Reset;
        let mut full = [0u8; crate::MAX_FRAME_LEN];
        let frame_len = encode_frame(&msg, &mut full).unwrap().len();
        for len in 0..frame_len {
            let mut out = [0u8; 16];
            assert_eq!(
                encode_frame(&msg, &mut out[..len]),
                Err(EncodeError::BufferTooSmall)
            );
        }
    }

    /// The in-place encoding is byte for byte the cobs crate's, for bodies with and without
    /// zeros, across the 254-byte block boundaries, up to the largest payload.
    #[test]
    fn in_place_encoding_matches_the_copy() {
        struct Raw<'a>(&'a [u8]);
        impl Serialize for Raw<'_> {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                use serde::ser::SerializeTuple;
                let mut t = s.serialize_tuple(self.0.len())?;
                for b in self.0 {
                    t.serialize_element(b)?;
                }
                t.end()
            }
        }
        let mut x = 0x9e37_79b9_u32;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        let mut body = [0u8; MAX_PAYLOAD_LEN + 1];
        for case in 0..3000usize {
            let len = match case % 4 {
                0 => case % 1030,
                1 => 250 + case % 12,
                2 => 500 + case % 16,
                _ => 1010 + case % 20,
            }
            .min(MAX_PAYLOAD_LEN + 1);
            let zeros = case % 5;
            for b in &mut body[..len] {
                *b = if zeros > 0 && next() % (zeros as u32 * 40) == 0 {
                    0
                } else {
                    next() as u8 | 1
                };
            }
            let msg = Raw(&body[..len]);
            let (mut a, mut b) = ([0u8; MAX_FRAME_LEN + 3], [0u8; MAX_FRAME_LEN + 3]);
            let fast =
                encode_in_place(&msg, &mut a[..MAX_FRAME_LEN + case % 3]).map(|f| f.to_vec());
            let slow = encode_via_copy(&msg, &mut b).map(|f| f.to_vec());
            assert_eq!(fast, slow, "case {case}, len {len}");
        }
    }

    #[test]
    fn frames_hold_zeros_only_at_both_ends() {
        let msg = crate::HostToCore::Imu(crate::ImuSample {
            t_us: 0,
            gyro: [0.0; 3],
            accel: [0.0, 0.0, 9.81],
            trigger: false,
        });
        let mut out = [0u8; crate::MAX_FRAME_LEN];
        let frame = encode_frame(&msg, &mut out).unwrap();
        assert_eq!(frame.iter().filter(|&&b| b == 0).count(), 2, "{frame:?}");
        assert_eq!((frame.first(), frame.last()), (Some(&0), Some(&0)));
    }
}
