//! SDO abort codes: the one answer every object access gives on failure. A leaf module, so
//! that the frame, COB-ID and dictionary code can name an abort without depending on the SDO
//! protocol.

/// SDO abort codes (CiA 301 table 22).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u32)]
pub enum SdoAbort {
    /// Toggle bit not alternated.
    ToggleBit = 0x0503_0000,
    /// SDO protocol timed out.
    Timeout = 0x0504_0000,
    /// Client/server command specifier not valid or unknown.
    UnknownCommand = 0x0504_0001,
    /// Invalid block size (block transfer).
    InvalidBlockSize = 0x0504_0002,
    /// Invalid sequence number (block transfer).
    InvalidSequence = 0x0504_0003,
    /// CRC error (block transfer).
    CrcError = 0x0504_0004,
    /// Out of memory.
    OutOfMemory = 0x0504_0005,
    /// Unsupported access to an object.
    UnsupportedAccess = 0x0601_0000,
    /// Attempt to read a write-only object.
    WriteOnly = 0x0601_0001,
    /// Attempt to write a read-only object.
    ReadOnly = 0x0601_0002,
    /// Object does not exist in the object dictionary.
    NoObject = 0x0602_0000,
    /// Object cannot be mapped to the PDO.
    NotMappable = 0x0604_0041,
    /// Number and length of the mapped objects would exceed the PDO length.
    PdoTooLong = 0x0604_0042,
    /// General parameter incompatibility.
    ParameterIncompatible = 0x0604_0043,
    /// General internal incompatibility in the device.
    InternalIncompatible = 0x0604_0047,
    /// Access failed due to a hardware error.
    Hardware = 0x0606_0000,
    /// Data type does not match, length of service parameter does not match.
    LengthMismatch = 0x0607_0010,
    /// Data type does not match, length of service parameter too high.
    TooLong = 0x0607_0012,
    /// Data type does not match, length of service parameter too low.
    TooShort = 0x0607_0013,
    /// Sub-index does not exist.
    NoSubIndex = 0x0609_0011,
    /// Invalid value for parameter (download only).
    InvalidValue = 0x0609_0030,
    /// Value of parameter written too high.
    ValueTooHigh = 0x0609_0031,
    /// Value of parameter written too low.
    ValueTooLow = 0x0609_0032,
    /// General error.
    General = 0x0800_0000,
    /// Data cannot be transferred or stored to the application.
    CannotStore = 0x0800_0020,
    /// ... because of local control.
    LocalControl = 0x0800_0021,
    /// ... because of the present device state.
    DeviceState = 0x0800_0022,
    /// No data available.
    NoData = 0x0800_0024,
}

impl SdoAbort {
    /// The 32-bit code sent in an abort frame.
    pub const fn code(self) -> u32 {
        self as u32
    }
}
