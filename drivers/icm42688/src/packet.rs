//! FIFO packet 3 (data sheet §6.1): header, accelerometer, gyro, temperature and time stamp, 16 bytes,
//! big-endian (INTF_CONFIG0 SENSOR_DATA_ENDIAN = 1).

use core::fmt;

use crate::registers as reg;
use crate::settings::Settings;

/// One FIFO packet 3 as read from the part (raw counts).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Packet {
    /// Header byte (data sheet §6.2); `header & 0xFC == 0x68` for a packet 3 with an ODR time stamp.
    pub header: u8,
    /// Accelerometer X, Y, Z in counts; −32768 marks an invalid sample.
    pub accel: [i16; 3],
    /// Gyro X, Y, Z in counts; −32768 marks an invalid sample.
    pub gyro: [i16; 3],
    /// Temperature in counts: °C = raw / 2.07 + 25.
    pub temperature: i8,
    /// Low 16 bits of the part's time-stamp counter at the sample (TMST_EN, TMST_DELTA_EN = 0,
    /// TMST_RES = 0), on the part's clock. Its tick is nominally 1 µs but 32/30 µs on the
    /// internal clock ([`Settings::stamp_tick`]): it wraps every 69.9 ms.
    pub timestamp: u16,
}

/// Why 16 FIFO bytes are not a packet 3.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PacketError {
    /// HEADER_MSG (bit 7) is set: the FIFO had no packet to give (an empty FIFO reads 0xFF).
    Empty(u8),
    /// The header is not that of a packet 3 with an ODR time stamp: the bytes are not
    /// aligned on a packet, or were corrupted on the way.
    BadHeader(u8),
}

impl fmt::Display for PacketError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PacketError::Empty(h) => write!(
                f,
                "FIFO header 0x{h:02X} has HEADER_MSG set: the FIFO was empty"
            ),
            PacketError::BadHeader(h) => write!(
                f,
                "FIFO header 0x{h:02X} is not a packet 3 with an ODR time stamp (0x68 under mask 0xFC)"
            ),
        }
    }
}

impl core::error::Error for PacketError {}

impl Packet {
    /// Length of a packet 3 in bytes.
    pub const LEN: usize = 16;

    /// Decodes 16 FIFO bytes, checking the header.
    pub fn decode(bytes: &[u8; 16]) -> Result<Packet, PacketError> {
        let [
            header,
            ax1,
            ax0,
            ay1,
            ay0,
            az1,
            az0,
            gx1,
            gx0,
            gy1,
            gy0,
            gz1,
            gz0,
            temperature,
            t1,
            t0,
        ] = *bytes;
        if header & reg::HEADER_MSG != 0 {
            return Err(PacketError::Empty(header));
        }
        if header & reg::HEADER_PACKET3_MASK != reg::HEADER_PACKET3 {
            return Err(PacketError::BadHeader(header));
        }
        Ok(Packet {
            header,
            accel: [
                i16::from_be_bytes([ax1, ax0]),
                i16::from_be_bytes([ay1, ay0]),
                i16::from_be_bytes([az1, az0]),
            ],
            gyro: [
                i16::from_be_bytes([gx1, gx0]),
                i16::from_be_bytes([gy1, gy0]),
                i16::from_be_bytes([gz1, gz0]),
            ],
            temperature: i8::from_be_bytes([temperature]),
            timestamp: u16::from_be_bytes([t1, t0]),
        })
    }

    /// Encodes the packet as the part would put it in the FIFO (big-endian).
    pub fn encode(&self) -> [u8; 16] {
        let [ax1, ax0] = self.accel[0].to_be_bytes();
        let [ay1, ay0] = self.accel[1].to_be_bytes();
        let [az1, az0] = self.accel[2].to_be_bytes();
        let [gx1, gx0] = self.gyro[0].to_be_bytes();
        let [gy1, gy0] = self.gyro[1].to_be_bytes();
        let [gz1, gz0] = self.gyro[2].to_be_bytes();
        let [temperature] = self.temperature.to_be_bytes();
        let [t1, t0] = self.timestamp.to_be_bytes();
        [
            self.header,
            ax1,
            ax0,
            ay1,
            ay0,
            az1,
            az0,
            gx1,
            gx0,
            gy1,
            gy0,
            gz1,
            gz0,
            temperature,
            t1,
            t0,
        ]
    }

    /// Temperature in °C: raw / 2.07 + 25 (FIFO temperature, data sheet §6.1).
    pub fn temperature_c(&self) -> f32 {
        f32::from(self.temperature) / 2.07 + 25.0
    }

    /// False when any axis holds −32768, the part's mark for an invalid sample (a sensor
    /// still starting up, or off), or when the header says the ODR changed at this packet
    /// (HEADER_ODR_ACCEL/GYRO: a rate change settling; PX4 drops such packets too).
    pub fn has_valid_data(&self) -> bool {
        self.header & reg::HEADER_ODR_CHANGED == 0
            && !self
                .accel
                .iter()
                .chain(self.gyro.iter())
                .any(|&v| v == reg::INVALID_SAMPLE)
    }

    /// Angular rate in rad/s with the settings' gyro range.
    pub fn gyro_rad_s(&self, settings: &Settings) -> [f32; 3] {
        let scale = settings.gyro_rad_s_per_lsb();
        self.gyro.map(|v| f32::from(v) * scale)
    }

    /// Specific force in m/s² with the settings' accelerometer range.
    pub fn accel_m_s2(&self, settings: &Settings) -> [f32; 3] {
        let scale = settings.accel_m_s2_per_lsb();
        self.accel.map(|v| f32::from(v) * scale)
    }
}
