//! SDO server (CiA 301 7.2.4): expedited and segmented transfers, abort codes.
//!
//! The server owns only the protocol state and a small transfer buffer; object access goes
//! through `ObjectAccess`, implemented by the device, so the protocol code never sees the
//! object dictionary's internals.

use crate::time::Instant;

/// Size of the segmented-transfer buffer: the longest object that can be uploaded or
/// downloaded (device strings are short; block transfer is not supported).
pub const SDO_BUFFER: usize = 32;

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

/// What the SDO server needs from the object dictionary. Every method checks existence and
/// access itself, so the server can report its abort code verbatim.
pub(crate) trait ObjectAccess {
    /// Reads an object for an upload into `buf`, returning the number of bytes.
    fn upload(&mut self, index: u16, sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort>;
    /// The object's size, for an expedited download that does not indicate one.
    fn size_of(&mut self, index: u16, sub: u8) -> Result<usize, SdoAbort>;
    /// Early checks of a segmented download (exists, writable, indicated size plausible).
    fn check_download(&mut self, index: u16, sub: u8, size: Option<u32>) -> Result<(), SdoAbort>;
    /// Fully checked write; must leave everything unchanged when it fails.
    fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort>;
}

/// SDO server transfer state, named after the CiA 301 protocols.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Transfer {
    Idle,
    SegmentedDownload {
        index: u16,
        sub: u8,
        toggle: bool,
        size: Option<u32>,
        deadline: Instant,
    },
    SegmentedUpload {
        index: u16,
        sub: u8,
        toggle: bool,
        deadline: Instant,
    },
}

/// The SDO server: one transfer at a time, replies built into 8-byte payloads.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct SdoServer {
    transfer: Transfer,
    buf: [u8; SDO_BUFFER],
    /// Bytes in `buf`: received so far (download) or to send in total (upload).
    len: u8,
    /// Bytes of `buf` already sent (upload).
    sent: u8,
    timeout_us: u64,
}

type Reply = Result<[u8; 8], SdoAbort>;

/// An initiate reply or abort: command byte, echoed multiplexer, 4 data bytes.
fn reply(cmd: u8, index: u16, sub: u8, data: [u8; 4]) -> [u8; 8] {
    let [i0, i1] = index.to_le_bytes();
    let [d0, d1, d2, d3] = data;
    [cmd, i0, i1, sub, d0, d1, d2, d3]
}

pub(crate) fn abort_payload(index: u16, sub: u8, abort: SdoAbort) -> [u8; 8] {
    reply(0x80, index, sub, abort.code().to_le_bytes())
}

impl SdoServer {
    pub(crate) const fn new(timeout_ms: u16) -> Self {
        Self {
            transfer: Transfer::Idle,
            buf: [0; SDO_BUFFER],
            len: 0,
            sent: 0,
            timeout_us: timeout_ms as u64 * 1000,
        }
    }

    /// Drops any transfer silently (client abort, NMT state change, reset).
    pub(crate) fn reset(&mut self) {
        self.transfer = Transfer::Idle;
    }

    fn mux(&self) -> Option<(u16, u8)> {
        match self.transfer {
            Transfer::Idle => None,
            Transfer::SegmentedDownload { index, sub, .. }
            | Transfer::SegmentedUpload { index, sub, .. } => Some((index, sub)),
        }
    }

    /// When the current transfer times out.
    pub(crate) fn deadline(&self) -> Option<Instant> {
        match self.transfer {
            Transfer::Idle => None,
            Transfer::SegmentedDownload { deadline, .. }
            | Transfer::SegmentedUpload { deadline, .. } => Some(deadline),
        }
    }

    /// Aborts a transfer the client has left unfinished for too long.
    pub(crate) fn poll(&mut self, now: Instant) -> Option<[u8; 8]> {
        let (index, sub) = self.mux()?;
        if self.deadline().is_some_and(|d| now < d) {
            return None;
        }
        self.reset();
        warn!("SDO {=u16:#x}:{=u8} timed out", index, sub);
        Some(abort_payload(index, sub, SdoAbort::Timeout))
    }

    /// Handles one client request (DLC already checked to be 8); returns the reply, if any.
    pub(crate) fn on_request(
        &mut self,
        now: Instant,
        req: &[u8; 8],
        od: &mut impl ObjectAccess,
    ) -> Option<[u8; 8]> {
        let [cmd, i0, i1, sub, d0, d1, d2, d3] = *req;
        let index = u16::from_le_bytes([i0, i1]);
        let data = [d0, d1, d2, d3];
        let deadline = now.add_micros(self.timeout_us);
        let ccs = cmd >> 5;
        // Segment requests carry no multiplexer: an abort then names the running transfer.
        let (abort_index, abort_sub) = match ccs {
            0 | 3 => self.mux().unwrap_or((index, sub)),
            _ => (index, sub),
        };
        let result = match ccs {
            0 => self.download_segment(cmd, req, deadline, od),
            1 => self.initiate_download(cmd, index, sub, data, deadline, od),
            2 => self.initiate_upload(index, sub, deadline, od),
            3 => self.upload_segment(cmd, deadline),
            4 => {
                // An abort from the client ends the transfer without an answer.
                self.reset();
                return None;
            }
            // 5 and 6 are block upload/download, 7 is undefined.
            _ => Err(SdoAbort::UnknownCommand),
        };
        match result {
            Ok(payload) => Some(payload),
            Err(abort) => {
                self.reset();
                warn!(
                    "SDO {=u16:#x}:{=u8} abort {=u32:#x}",
                    abort_index,
                    abort_sub,
                    abort.code()
                );
                Some(abort_payload(abort_index, abort_sub, abort))
            }
        }
    }

    fn initiate_download(
        &mut self,
        cmd: u8,
        index: u16,
        sub: u8,
        data: [u8; 4],
        deadline: Instant,
        od: &mut impl ObjectAccess,
    ) -> Reply {
        // A new initiate replaces whatever transfer was pending.
        self.reset();
        let expedited = cmd & 0x02 != 0;
        let size_indicated = cmd & 0x01 != 0;
        if expedited {
            let len = if size_indicated {
                4 - usize::from((cmd >> 2) & 0x03)
            } else {
                // 0x22: the client left the size to the object (strings: all 4 bytes).
                od.size_of(index, sub)?.min(4)
            };
            od.download(index, sub, data.get(..len).unwrap_or(&data))?;
        } else {
            let size = size_indicated.then(|| u32::from_le_bytes(data));
            od.check_download(index, sub, size)?;
            self.len = 0;
            self.transfer = Transfer::SegmentedDownload {
                index,
                sub,
                toggle: false,
                size,
                deadline,
            };
        }
        Ok(reply(0x60, index, sub, [0; 4]))
    }

    fn download_segment(
        &mut self,
        cmd: u8,
        req: &[u8; 8],
        deadline: Instant,
        od: &mut impl ObjectAccess,
    ) -> Reply {
        let Transfer::SegmentedDownload {
            index,
            sub,
            toggle,
            size,
            ..
        } = self.transfer
        else {
            return Err(SdoAbort::UnknownCommand);
        };
        if (cmd & 0x10 != 0) != toggle {
            return Err(SdoAbort::ToggleBit);
        }
        let unused = usize::from((cmd >> 1) & 0x07);
        let segment = req.get(1..8 - unused).unwrap_or(&[]);
        let start = usize::from(self.len);
        let end = start + segment.len();
        self.buf
            .get_mut(start..end)
            .ok_or(SdoAbort::TooLong)?
            .copy_from_slice(segment);
        // end <= SDO_BUFFER, checked by the slice above.
        self.len = end as u8;
        if cmd & 0x01 != 0 {
            if size.is_some_and(|s| s != end as u32) {
                return Err(SdoAbort::LengthMismatch);
            }
            od.download(index, sub, self.buf.get(..end).unwrap_or(&[]))?;
            self.reset();
        } else {
            self.transfer = Transfer::SegmentedDownload {
                index,
                sub,
                toggle: !toggle,
                size,
                deadline,
            };
        }
        Ok([0x20 | (cmd & 0x10), 0, 0, 0, 0, 0, 0, 0])
    }

    fn initiate_upload(
        &mut self,
        index: u16,
        sub: u8,
        deadline: Instant,
        od: &mut impl ObjectAccess,
    ) -> Reply {
        self.reset();
        let len = od.upload(index, sub, &mut self.buf)?.min(SDO_BUFFER);
        if (1..=4).contains(&len) {
            let mut data = [0u8; 4];
            if let (Some(dst), Some(src)) = (data.get_mut(..len), self.buf.get(..len)) {
                dst.copy_from_slice(src);
            }
            // e = 1, s = 1, n = number of unused bytes.
            let cmd = 0x43 | (((4 - len) as u8) << 2);
            return Ok(reply(cmd, index, sub, data));
        }
        // Longer (or empty) values go segmented with the size indicated.
        self.len = len as u8;
        self.sent = 0;
        self.transfer = Transfer::SegmentedUpload {
            index,
            sub,
            toggle: false,
            deadline,
        };
        Ok(reply(0x41, index, sub, (len as u32).to_le_bytes()))
    }

    fn upload_segment(&mut self, cmd: u8, deadline: Instant) -> Reply {
        let Transfer::SegmentedUpload {
            index, sub, toggle, ..
        } = self.transfer
        else {
            return Err(SdoAbort::UnknownCommand);
        };
        if (cmd & 0x10 != 0) != toggle {
            return Err(SdoAbort::ToggleBit);
        }
        let rest = self
            .buf
            .get(usize::from(self.sent)..usize::from(self.len))
            .unwrap_or(&[]);
        let n = rest.len().min(7);
        let last = rest.len() <= 7;
        let mut out = [0u8; 8];
        if let (Some(dst), Some(src)) = (out.get_mut(1..=n), rest.get(..n)) {
            dst.copy_from_slice(src);
        }
        out[0] = (cmd & 0x10) | (((7 - n) as u8) << 1) | u8::from(last);
        // n <= 7 and sent + n <= len <= SDO_BUFFER: no overflow.
        self.sent += n as u8;
        self.transfer = if last {
            Transfer::Idle
        } else {
            Transfer::SegmentedUpload {
                index,
                sub,
                toggle: !toggle,
                deadline,
            }
        };
        Ok(out)
    }
}
