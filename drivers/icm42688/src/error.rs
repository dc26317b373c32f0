//! The driver's error type.

use core::fmt;

use crate::registers::WHO_AM_I_VALUE;
use crate::settings::SettingsError;

/// What went wrong talking to the part. `E` is the SPI device's error type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Error<E> {
    /// The SPI transaction failed.
    Spi(E),
    /// WHO_AM_I did not read 0x47: another part, or no part (a floating MISO reads 0x00 or
    /// 0xFF), or a wrong SPI mode.
    WrongId(u8),
    /// The part answered but did not finish its soft reset within 1 s (DEVICE_CONFIG's reset
    /// bit stayed set, or RESET_DONE never came).
    ResetTimeout,
    /// The settings cannot be given to the part.
    Settings(SettingsError),
}

impl<E> From<SettingsError> for Error<E> {
    fn from(e: SettingsError) -> Self {
        Error::Settings(e)
    }
}

impl<E: fmt::Debug> fmt::Display for Error<E> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Spi(e) => write!(f, "SPI transaction with the ICM-42688-P failed: {e:?}"),
            Error::WrongId(got) => write!(
                f,
                "ICM-42688-P WHO_AM_I read 0x{got:02X}, expected 0x{WHO_AM_I_VALUE:02X} \
                 (another part, no part, or a wrong SPI mode)"
            ),
            Error::ResetTimeout => {
                f.write_str("ICM-42688-P did not finish its soft reset within 1 s (no RESET_DONE)")
            }
            Error::Settings(e) => write!(f, "invalid ICM-42688-P settings: {e}"),
        }
    }
}

impl<E: fmt::Debug> core::error::Error for Error<E> {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            Error::Settings(e) => Some(e),
            _ => None,
        }
    }
}
