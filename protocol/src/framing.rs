//! Framing: `0x00 ‖ COBS(postcard(msg) ‖ CRC-32C(postcard(msg)) as little-endian u32) ‖ 0x00`.
//!
//! COBS removes every zero byte from the frame, so `0x00` marks frame boundaries unambiguously
//! and a receiver that lost sync finds the next frame at the next zero. Each frame is delimited
//! on both sides: if a frame's closing delimiter is corrupted, the next frame's opening one
//! still ends the damage there, so only the corrupted frame is lost. (The receiver skips the
//! empty frame between two delimiters.) The CRC-32C (Castagnoli,
//! reflected, init and xor-out `0xFFFFFFFF`, check value `0xE3069283`) detects corruption.

use crc::{CRC_32_ISCSI, Crc};
use serde::Serialize;

use crate::error::EncodeError;
use crate::limits::{CRC_LEN, MAX_PAYLOAD_LEN};

const CASTAGNOLI: Crc<u32> = Crc::<u32>::new(&CRC_32_ISCSI);

/// CRC-32C of `bytes`.
pub fn crc32c(bytes: &[u8]) -> u32 {
    CASTAGNOLI.checksum(bytes)
}

/// Length of `msg`'s postcard body (without CRC, COBS and delimiter).
pub fn body_len<T: Serialize>(msg: &T) -> Result<usize, EncodeError> {
    postcard::experimental::serialized_size(msg).map_err(|_| EncodeError::PayloadTooLarge)
}

/// Encodes `msg` as one complete frame (both delimiters included) into `out` and returns the frame.
/// `out` of [`crate::MAX_FRAME_LEN`] bytes always suffices for the protocol's messages.
pub fn encode_frame<'o, T: Serialize>(msg: &T, out: &'o mut [u8]) -> Result<&'o [u8], EncodeError> {
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
