//! Size bounds of the protocol. Every buffer on either end is sized from these constants.

/// Most correspondences carried by one [`crate::Correspondences`] message. A frame with more
/// is split by the sender into several parts ([`crate::Correspondences::split`]).
pub const MAX_CORRESPONDENCES_PER_MESSAGE: usize = 16;

/// Most parts one camera frame's correspondences may be split into.
pub const MAX_PARTS_PER_FRAME: usize = 8;

/// Most correspondences one camera frame may carry in all its parts.
pub const MAX_CORRESPONDENCES_PER_FRAME: usize =
    MAX_CORRESPONDENCES_PER_MESSAGE * MAX_PARTS_PER_FRAME;

/// Length of the CRC-32C that follows the postcard body inside a frame.
pub const CRC_LEN: usize = 4;

/// Largest postcard body of any message (a test checks the worst-case instance of every
/// message kind against it).
pub const MAX_PAYLOAD_LEN: usize = 1024;

/// Largest frame on the wire, in bytes: COBS of body and CRC between two `0x00` delimiters.
pub const MAX_FRAME_LEN: usize = cobs::max_encoding_length(MAX_PAYLOAD_LEN + CRC_LEN) + 2;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_bound_is_body_crc_cobs_overhead_and_delimiters() {
        // 1028 bytes need ceil(1028 / 254) = 5 COBS code bytes.
        assert_eq!(MAX_FRAME_LEN, 1024 + 4 + 5 + 2);
    }
}
