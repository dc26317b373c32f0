//! Typed errors: framing errors on either end, and the error codes the core reports.

use core::fmt;

use serde::{Deserialize, Serialize};

use crate::version::Version;

/// Why a received frame was rejected. The decoder has already resynchronised when it reports
/// one of these: the next frame after the delimiter decodes normally.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DecodeError {
    /// More bytes than [`crate::MAX_FRAME_LEN`] arrived before a delimiter; they were dropped.
    Oversized,
    /// The bytes between two delimiters are not valid COBS.
    Cobs,
    /// The decoded frame is shorter than a CRC plus one byte of message.
    Truncated,
    /// The CRC-32C does not match the body.
    Crc,
    /// The CRC matched but the body is not a valid message of the expected direction.
    Malformed,
    /// The body decoded to a message but bytes were left over.
    TrailingBytes,
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DecodeError::Oversized => "frame longer than the protocol's maximum frame length",
            DecodeError::Cobs => "frame is not valid COBS",
            DecodeError::Truncated => "frame too short to hold a CRC and a message",
            DecodeError::Crc => "frame CRC-32C mismatch (corrupted frame)",
            DecodeError::Malformed => "frame body is not a valid message",
            DecodeError::TrailingBytes => "frame body has bytes after the message",
        })
    }
}

impl core::error::Error for DecodeError {}

/// Why a message could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EncodeError {
    /// The message body exceeds [`crate::MAX_PAYLOAD_LEN`] (cannot happen for the protocol's
    /// own message types; guards generic use).
    PayloadTooLarge,
    /// The output buffer is smaller than the encoded frame; size it with
    /// [`crate::MAX_FRAME_LEN`].
    BufferTooSmall,
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            EncodeError::PayloadTooLarge => "message body exceeds the protocol's maximum payload",
            EncodeError::BufferTooSmall => "output buffer smaller than the encoded frame",
        })
    }
}

impl core::error::Error for EncodeError {}

/// The field of a host message that failed validation.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InvalidField {
    /// A noise parameter is out of range: negative, not finite, with a square that is not a
    /// normal f32, or a measurement noise (of the gyroscope, and of the accelerometer in the
    /// models that use it) that is zero.
    NoiseParams,
    /// An initial standard deviation is not positive, or its square is not a normal f32.
    InitSigma,
    /// The hand-eye rotation is not a unit quaternion, or a value is not finite.
    HandEye,
    /// The outlier gate is not positive or not finite.
    Gate,
    /// A divergence threshold is out of range (λ outside (0, 1), or a threshold ≤ 0).
    Divergence,
    /// A rate is not positive and finite.
    Rate,
    /// The still window is empty.
    StillSamples,
    /// An `Init` position is not finite.
    InitPosition,
    /// An `Init` yaw or orientation is not finite or not a unit quaternion.
    InitAttitude,
    /// An IMU sample holds a non-finite value.
    ImuNotFinite,
    /// An IMU sample is beyond any real sensor's range ([`crate::validate::MAX_GYRO_RAD_S`],
    /// [`crate::validate::MAX_ACCEL_M_S2`]).
    ImuOutOfRange,
    /// A correspondence part index or count is out of range.
    CorrespondencePart,
    /// Correspondence `index` (within its message) holds a non-finite point.
    CorrespondenceNotFinite {
        /// Index within the message.
        index: u8,
    },
    /// Correspondence `index` has a model-point covariance that is not positive
    /// semi-definite, or an image-point covariance that is not positive definite.
    CorrespondenceCovariance {
        /// Index within the message.
        index: u8,
    },
    /// `divergence.covariance_frobenius` is below
    /// [`crate::validate::COVARIANCE_THRESHOLD_MARGIN`] times the norm of the initial
    /// covariance that `init_sigma` gives: the test would fire right after every
    /// initialisation.
    CovarianceThreshold,
    /// `session` is 0, which a [`crate::HelloAck`] reports for a core with no configuration
    /// (since 3.0).
    Session,
    /// A `Resume` state that is not finite, or whose quaternion is not a unit one (since 3.0).
    Resume,
    /// A `Sampling` request with `trigger_every` above
    /// [`crate::validate::MAX_TRIGGER_EVERY`], or `raw_imu` with the host sampling (since 3.1).
    Sampling,
    /// Contour correspondence `index` (within its message) has a normal that is not a unit
    /// vector (since 3.2).
    ContourNormal {
        /// Index within the message.
        index: u8,
    },
}

impl fmt::Display for InvalidField {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            InvalidField::NoiseParams => f.write_str(
                "noise parameter out of range (negative, not finite, square not a normal f32, \
                 or a measurement noise of zero)",
            ),
            InvalidField::InitSigma => {
                f.write_str("initial sigma not positive, or its square not a normal f32")
            }
            InvalidField::HandEye => f.write_str("hand-eye rotation not a unit quaternion"),
            InvalidField::Gate => f.write_str("outlier gate not positive"),
            InvalidField::Divergence => f.write_str(
                "divergence parameter out of range (residual low-pass outside (0, 1), or a \
                 threshold not positive)",
            ),
            InvalidField::Rate => f.write_str("rate not positive"),
            InvalidField::StillSamples => f.write_str("still window is empty"),
            InvalidField::InitPosition => f.write_str("init position not finite"),
            InvalidField::InitAttitude => f.write_str("init yaw/orientation invalid"),
            InvalidField::ImuNotFinite => f.write_str("IMU sample not finite"),
            InvalidField::ImuOutOfRange => f.write_str("IMU sample beyond any sensor's range"),
            InvalidField::CorrespondencePart => f.write_str("correspondence part out of range"),
            InvalidField::CorrespondenceNotFinite { index } => {
                write!(f, "correspondence {index} not finite")
            }
            InvalidField::CorrespondenceCovariance { index } => {
                write!(
                    f,
                    "correspondence {index} covariance invalid (image point's not positive \
                     definite, or model point's not positive semi-definite)"
                )
            }
            InvalidField::CovarianceThreshold => f.write_str(
                "divergence covariance threshold below twice the initial covariance's norm \
                 (from init_sigma): it would fire after every initialisation",
            ),
            InvalidField::Session => {
                f.write_str("session id 0 (reserved for a core with no configuration)")
            }
            InvalidField::Resume => {
                f.write_str("resume state not finite, or its quaternion not a unit one")
            }
            InvalidField::Sampling => f.write_str(
                "sampling request invalid (trigger_every above the limit, or raw IMU asked of \
                 a core the host samples for)",
            ),
            InvalidField::ContourNormal { index } => {
                write!(
                    f,
                    "contour correspondence {index}: normal not a unit vector"
                )
            }
        }
    }
}

impl core::error::Error for InvalidField {}

/// Error codes the core reports in [`crate::CoreToHost::Error`].
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ErrorCode {
    /// The host's major protocol version differs from the core's (variant index frozen at 0).
    VersionMismatch {
        /// The core's version.
        core: Version,
        /// The version the host announced.
        host: Version,
    },
    /// A received frame was rejected.
    Decode(DecodeError),
    /// A message field failed validation; the message was ignored.
    Invalid(InvalidField),
    /// A message other than `Hello` arrived before the handshake.
    NoHandshake,
    /// A message that needs a configuration arrived before `Configure`.
    NotConfigured,
    /// An IMU time stamp did not increase.
    TimestampNotIncreasing {
        /// Previous time stamp [µs].
        last_us: u64,
        /// Offending time stamp [µs].
        got_us: u64,
    },
    /// The gap between two IMU samples exceeds what the core integrates in one step.
    TimestampGap {
        /// Previous time stamp [µs].
        last_us: u64,
        /// Offending time stamp [µs].
        got_us: u64,
    },
    /// More correspondences for one frame than the core holds.
    TooManyCorrespondences {
        /// Frame id.
        frame_id: u32,
    },
    /// An `Imu` sample reached a core configured for the vision-only model, which has no
    /// inertial measurements: its time is advanced by `Tick` (since 2.1).
    ImuInVisionModel,
    /// A `Tick` reached a core configured for an inertial model, which is advanced by `Imu`
    /// samples (since 2.1).
    TickInInertialModel,
    /// The vision-only model has no gravity to find roll and pitch: it starts only from
    /// `InitAttitude::Full` (since 2.1).
    VisionNeedsFullPose,
    /// The host asked the core to sample its own IMU, and it has none (since 3.1).
    NoOnboardImu,
    /// An `Imu` sample or a `Tick` came from the host while the core samples its own IMU
    /// (since 3.1).
    HostImuWhileCoreSamples,
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ErrorCode::VersionMismatch { core, host } => write!(
                f,
                "protocol version mismatch: core speaks {core}, host speaks {host}"
            ),
            ErrorCode::Decode(e) => write!(f, "frame rejected: {e}"),
            ErrorCode::Invalid(field) => write!(f, "invalid message: {field}"),
            ErrorCode::NoHandshake => f.write_str("message before Hello"),
            ErrorCode::NotConfigured => f.write_str("message before Configure"),
            ErrorCode::TimestampNotIncreasing { last_us, got_us } => {
                write!(f, "IMU time stamp {got_us} µs not after {last_us} µs")
            }
            ErrorCode::TimestampGap { last_us, got_us } => {
                write!(f, "IMU time stamp gap from {last_us} µs to {got_us} µs")
            }
            ErrorCode::TooManyCorrespondences { frame_id } => {
                write!(
                    f,
                    "frame {frame_id} has more correspondences than the core holds"
                )
            }
            ErrorCode::ImuInVisionModel => f.write_str(
                "IMU sample sent to a core configured for the vision-only model: send Tick instead",
            ),
            ErrorCode::TickInInertialModel => f.write_str(
                "Tick sent to a core configured for an inertial model: send Imu samples instead",
            ),
            ErrorCode::VisionNeedsFullPose => f.write_str(
                "the vision-only model has no gravity for roll and pitch: Init needs the full orientation",
            ),
            ErrorCode::NoOnboardImu => {
                f.write_str("the core has no IMU of its own: the host must send the samples")
            }
            ErrorCode::HostImuWhileCoreSamples => f.write_str(
                "IMU sample or Tick from the host while the core samples its own IMU: send \
                 Sampling with the host as the source first",
            ),
        }
    }
}

impl core::error::Error for ErrorCode {}
