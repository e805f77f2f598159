//! CiA 302-3 program download into the application slot (docs/FIRMWARE-UPDATE.md, "0x1F50:1
//! program data"), sans-I/O over the board's flash trait ([`Flash`]).
//!
//! The image is never valid while incomplete: "clear" erases the header page (the mark goes
//! first), the stream is programmed as it arrives with each page erased when the stream
//! first reaches it, the first four bytes (the mark) are held back, and only when the whole
//! image is in flash and its CRC over the flash content matches is the mark programmed, as
//! the very last write. A power cut at any instant therefore leaves either no valid image
//! (the loader stays) or, once the mark is complete, the new one.

use canopen_slave::SdoAbort;

use crate::header::{Crc32, DeviceId, HeaderError, ImageHeader, HEADER_LEN, MAGIC};
use crate::layout::{
    APP_ORIGIN, HEADER_SLOT, PAGE_SIZE, RAM_LENGTH, RAM_ORIGIN, SLOT_PAGES, SLOT_SIZE,
};

/// The application slot's flash, as the loader drives it: the board's flash trait over a
/// region that is the slot (offsets and pages relative to its origin, `HEADER`,
/// 0x0800_3000: pages `0..SLOT_PAGES` of [`PAGE_SIZE`] bytes; nothing outside it is
/// reachable), the one both images' flash code and tests use.
pub use handwheel_board::flash::{Flash, FlashError};

use handwheel_board::flash::{program_half_word, read};

/// 0x1F57:1 bit 0: a download runs.
pub const FLASH_IN_PROGRESS: u32 = 0x01;
/// 0x1F57:1 bits 1-7: the code ([`FlashStatus`]), shifted by [`FLASH_CODE_SHIFT`] and
/// masked by [`FLASH_CODE_MASK`].
pub const FLASH_CODE_SHIFT: u32 = 1;
/// The code's bits once shifted (CiA 302-3: 0..63 its own, 64..127 the manufacturer's).
pub const FLASH_CODE_MASK: u32 = 0x7F;

/// 0x1F57:1 bits 1-7: the flash status code.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum FlashStatus {
    /// No error.
    Ok = 0,
    /// No valid application (at boot, or since a failed download's clear was not followed
    /// by a complete one).
    NoValidProgram = 1,
    /// The header's magic, format or size unknown, or another device's image.
    FormatUnknown = 2,
    /// The CRC does not match, or the stream ended short or ran past `length`.
    FormatError = 3,
    /// Program data before "clear".
    NotCleared = 4,
    /// An erase or program failed or read back wrong.
    WriteError = 5,
    /// The image does not fit the slot.
    AddressError = 6,
    /// The application was started [`MAX_TRIAL_STARTS`](crate::boot::MAX_TRIAL_STARTS)
    /// times in a row and never confirmed that it is healthy on the bus (a hang, a fault, a
    /// lock-up, each ended by the watchdog): the loader stayed. The first code of the range
    /// CiA 302-3 leaves to the manufacturer (64..127).
    TrialFailed = 64,
}

impl FlashStatus {
    /// Every code the loader reports, in order.
    pub const ALL: [Self; 8] = [
        Self::Ok,
        Self::NoValidProgram,
        Self::FormatUnknown,
        Self::FormatError,
        Self::NotCleared,
        Self::WriteError,
        Self::AddressError,
        Self::TrialFailed,
    ];

    /// The code in one line for an operator (the host command prints it after the code;
    /// `cargo xtask contract` hands it to Python).
    #[must_use]
    pub const fn meaning(self) -> &'static str {
        match self {
            Self::Ok => "no error",
            Self::NoValidProgram => "no valid program",
            Self::FormatUnknown => {
                "data format unknown (the header's magic, format or size, or another device's \
                 image)"
            }
            Self::FormatError => {
                "data format error (the CRC does not match, or the stream ended short or ran \
                 past its length)"
            }
            Self::NotCleared => "flash not cleared (data before clear)",
            Self::WriteError => "flash write error (an erase or program failed or read back wrong)",
            Self::AddressError => "general address error (the image does not fit the slot)",
            // MAX_TRIAL_STARTS (a test checks the number).
            Self::TrialFailed => {
                "the application was started 3 times and never became healthy on the bus (a \
                 hang, a fault or a lock-up before it talks): the loader stays"
            }
        }
    }

    /// The SDO abort that reports this failure (the contract's table); `None` for the
    /// codes no transfer gives.
    #[must_use]
    pub const fn abort(self) -> Option<SdoAbort> {
        match self {
            Self::Ok | Self::NoValidProgram | Self::TrialFailed => None,
            Self::FormatUnknown => Some(SdoAbort::InvalidValue),
            Self::FormatError => Some(SdoAbort::CannotStore),
            Self::NotCleared => Some(SdoAbort::DeviceState),
            Self::WriteError => Some(SdoAbort::Hardware),
            Self::AddressError => Some(SdoAbort::OutOfMemory),
        }
    }
}

/// 0x1F51:1 as read: the state of the program.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Control {
    /// 0: nothing running, no download accepted.
    Stopped = 0,
    /// 1: a start was accepted (the loader resets into the application).
    Started = 1,
    /// 3: cleared, program data accepted.
    Cleared = 3,
}

/// What a write of 0x1F51:1 asks of the node once the SDO answer is out.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ControlAction {
    /// Nothing more.
    None,
    /// A valid application is in the slot: reset (the boot decision starts it).
    Start,
}

/// Whether the application's vector table is plausible: the initial stack pointer inside
/// `RAM` (word-aligned, the top of `RAM` allowed) and the reset vector a Thumb address
/// inside the image (`length` bytes from `FLASH`'s origin).
#[must_use]
pub fn vector_table_ok(stack_pointer: u32, reset: u32, length: u32) -> bool {
    let sp_ok = stack_pointer > RAM_ORIGIN
        && stack_pointer <= RAM_ORIGIN + RAM_LENGTH
        && stack_pointer.is_multiple_of(4);
    let entry = reset & !1;
    let reset_ok =
        reset & 1 == 1 && entry >= APP_ORIGIN && entry - APP_ORIGIN < length.min(SLOT_SIZE as u32);
    sp_ok && reset_ok
}

/// The CRC-32 of `len` slot bytes from `offset`, as the flash reads now (one copy for every
/// flash type, as [`check_application`]).
#[inline(never)]
fn flash_crc(flash: &dyn Flash, offset: usize, len: usize) -> u32 {
    let mut crc = Crc32::new();
    let mut buf = [0u8; 64];
    let mut at = 0;
    while at < len {
        let n = (len - at).min(buf.len());
        let chunk = &mut buf[..n];
        read(flash, offset + at, chunk);
        crc = crc.update(chunk);
        at += n;
    }
    crc.finish()
}

fn read_word(flash: &dyn Flash, offset: usize) -> u32 {
    let mut w = [0; 4];
    read(flash, offset, &mut w);
    u32::from_le_bytes(w)
}

/// The application in the slot if it is valid (the boot decision): the mark, a known format
/// for `device`, a length that fits, a plausible vector table and the CRC of the flash
/// content.
#[must_use]
pub fn valid_application(flash: &impl Flash, device: DeviceId) -> Option<ImageHeader> {
    check_application(flash, device)
}

/// [`valid_application`] over any flash, in one copy: the loader checks through two flash
/// types (before and after it takes the flash controller) and has no flash to spare for two.
#[inline(never)]
fn check_application(flash: &dyn Flash, device: DeviceId) -> Option<ImageHeader> {
    let mut head = [0u8; HEADER_LEN];
    read(flash, 0, &mut head);
    let header = ImageHeader::parse(&head).ok()?;
    header.check(device).ok()?;
    let sp = read_word(flash, HEADER_SLOT);
    let reset = read_word(flash, HEADER_SLOT + 4);
    if !vector_table_ok(sp, reset, header.length) {
        return None;
    }
    (flash_crc(flash, HEADER_SLOT, header.image_len()) == header.crc).then_some(header)
}

/// The program download state machine: 0x1F50:1, 0x1F51:1, 0x1F56:1 and 0x1F57:1 of the
/// loader.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Program {
    device: DeviceId,
    control: Control,
    status: FlashStatus,
    /// A 0x1F50 download runs (0x1F57 bit 0).
    streaming: bool,
    /// 0x1F56: the CRC of the valid application, 0 when none.
    software_id: u32,
    /// Bytes of the stream received so far.
    received: usize,
    /// The size the SDO client indicated.
    size: Option<usize>,
    /// The stream's first [`HEADER_LEN`] bytes, the mark among them, held back until the
    /// header is complete (the mark until the very end).
    head: [u8; HEADER_LEN],
    /// The header, once checked.
    header: Option<ImageHeader>,
    /// The byte at an even offset waiting for its odd partner (segments are 1..7 bytes).
    carry: Option<u8>,
    /// Slot pages erased since the clear: `0..erased` (the stream goes in order).
    erased: usize,
}

impl Program {
    /// The state at boot over the slot as it is: stopped, with 0x1F56 the CRC of a valid
    /// application and 0x1F57 "no valid program" without one.
    #[must_use]
    pub fn new(device: DeviceId, flash: &impl Flash) -> Self {
        let valid = valid_application(flash, device);
        Self {
            device,
            control: Control::Stopped,
            status: if valid.is_some() {
                FlashStatus::Ok
            } else {
                FlashStatus::NoValidProgram
            },
            streaming: false,
            software_id: valid.map_or(0, |h| h.crc),
            received: 0,
            size: None,
            head: [0xFF; HEADER_LEN],
            header: None,
            carry: None,
            erased: 0,
        }
    }

    /// The device images must be for.
    #[must_use]
    pub const fn device(&self) -> DeviceId {
        self.device
    }

    /// 0x1F51:1 as read.
    #[must_use]
    pub const fn control(&self) -> Control {
        self.control
    }

    /// The flash status code (0x1F57 bits 1-7).
    #[must_use]
    pub const fn status(&self) -> FlashStatus {
        self.status
    }

    /// Whether a download runs (0x1F57 bit 0).
    #[must_use]
    pub const fn in_progress(&self) -> bool {
        self.streaming
    }

    /// 0x1F56:1: the CRC of the valid application, 0 when none.
    #[must_use]
    pub const fn software_id(&self) -> u32 {
        self.software_id
    }

    /// 0x1F57:1: the status code in bits 1-7, "in progress" in bit 0.
    #[must_use]
    pub const fn flash_status(&self) -> u32 {
        ((self.status as u32) << FLASH_CODE_SHIFT) | (self.streaming as u32 * FLASH_IN_PROGRESS)
    }

    /// Bytes of the running (or last) stream received.
    #[must_use]
    pub const fn received(&self) -> usize {
        self.received
    }

    /// The loader stayed because the application it holds failed its trial boot
    /// ([`FlashStatus::TrialFailed`] until the next "clear").
    pub fn report_failed_trial(&mut self) {
        self.status = FlashStatus::TrialFailed;
    }

    /// A download failed: the application is invalid, and the next needs a clear.
    fn fail(&mut self, status: FlashStatus) -> SdoAbort {
        self.control = Control::Stopped;
        self.streaming = false;
        self.software_id = 0;
        self.status = status;
        status.abort().unwrap_or(SdoAbort::General)
    }

    /// A write of 0x1F51:1 (the caller checked the NMT state and the length).
    pub fn write_control(
        &mut self,
        value: u8,
        flash: &mut impl Flash,
    ) -> Result<ControlAction, SdoAbort> {
        match value {
            // Stop: the loader runs nothing.
            0 => Ok(ControlAction::None),
            1 => match valid_application(flash, self.device) {
                Some(_) => {
                    self.control = Control::Started;
                    Ok(ControlAction::Start)
                }
                None => Err(SdoAbort::DeviceState),
            },
            3 => self.clear(flash).map(|()| ControlAction::None),
            // 2 reset, and everything else.
            _ => Err(SdoAbort::InvalidValue),
        }
    }

    /// "Clear": erases the header page (the application is invalid from here on) and
    /// accepts program data.
    fn clear(&mut self, flash: &mut impl Flash) -> Result<(), SdoAbort> {
        self.streaming = false;
        self.software_id = 0;
        self.erased = 0;
        self.erase(0, flash)
            .map_err(|()| self.fail(FlashStatus::WriteError))?;
        self.control = Control::Cleared;
        self.status = FlashStatus::Ok;
        Ok(())
    }

    /// Erases slot page `page` and checks that it reads erased.
    fn erase(&mut self, page: usize, flash: &mut impl Flash) -> Result<(), ()> {
        if page >= SLOT_PAGES {
            return Err(());
        }
        flash.erase(page).map_err(|_| ())?;
        let erased = flash.page(page);
        if erased.len() != PAGE_SIZE || erased.iter().any(|&b| b != 0xFF) {
            return Err(());
        }
        self.erased = page + 1;
        Ok(())
    }

    /// The start of a 0x1F50:1 download of `size` bytes, if indicated.
    pub fn begin(&mut self, size: Option<u32>) -> Result<(), SdoAbort> {
        if self.streaming {
            // The previous stream ended without its last segment.
            self.abandon();
        }
        if self.control != Control::Cleared {
            self.status = FlashStatus::NotCleared;
            return Err(SdoAbort::DeviceState);
        }
        let size = size.map(|s| usize::try_from(s).unwrap_or(usize::MAX));
        if size.is_some_and(|s| s > SLOT_SIZE) {
            return Err(self.fail(FlashStatus::AddressError));
        }
        self.streaming = true;
        self.received = 0;
        self.size = size;
        self.head = [0xFF; HEADER_LEN];
        self.header = None;
        self.carry = None;
        Ok(())
    }

    /// The transfer ended without its last segment (client abort, timeout, NMT): the
    /// stream "ends short".
    pub fn abandon(&mut self) {
        if self.streaming {
            self.fail(FlashStatus::FormatError);
        }
    }

    /// The next bytes of the stream (any length, odd ones included).
    pub fn write(&mut self, data: &[u8], flash: &mut impl Flash) -> Result<(), SdoAbort> {
        if !self.streaming {
            self.status = FlashStatus::NotCleared;
            return Err(SdoAbort::DeviceState);
        }
        for &byte in data {
            let pos = self.received;
            if self
                .header
                .is_some_and(|h| pos >= HEADER_SLOT + h.image_len())
            {
                // Runs past `length`.
                return Err(self.fail(FlashStatus::FormatError));
            }
            self.received += 1;
            if let Some(slot) = self.head.get_mut(pos) {
                *slot = byte;
                if pos == HEADER_LEN - 1 {
                    self.take_header(flash)?;
                }
                continue;
            }
            if pos.is_multiple_of(2) {
                self.carry = Some(byte);
            } else {
                let low = self.carry.take().unwrap_or(0xFF);
                self.put(pos - 1, [low, byte], flash)?;
            }
        }
        Ok(())
    }

    /// The header is complete: checks it, then programs it but for the mark.
    fn take_header(&mut self, flash: &mut impl Flash) -> Result<(), SdoAbort> {
        let header = match ImageHeader::parse(&self.head) {
            Ok(h) => h,
            Err(_) => return Err(self.fail(FlashStatus::FormatUnknown)),
        };
        match header.check(self.device) {
            Ok(()) => {}
            Err(HeaderError::TooLarge) => return Err(self.fail(FlashStatus::AddressError)),
            Err(_) => return Err(self.fail(FlashStatus::FormatUnknown)),
        }
        let total = HEADER_SLOT + header.image_len();
        if self.size.is_some_and(|s| s != total) {
            // The indicated size says the stream will end short or run past `length`.
            return Err(self.fail(FlashStatus::FormatError));
        }
        self.header = Some(header);
        let head = self.head;
        for (i, pair) in head.chunks_exact(2).enumerate().skip(2) {
            self.put(2 * i, [pair[0], pair[1]], flash)?;
        }
        Ok(())
    }

    /// Programs the half-word `bytes` at the even slot `offset`, erasing its page first if
    /// the stream reaches it for the first time, and reads it back.
    fn put(
        &mut self,
        offset: usize,
        bytes: [u8; 2],
        flash: &mut impl Flash,
    ) -> Result<(), SdoAbort> {
        let page = offset / PAGE_SIZE;
        while self.erased <= page {
            let next = self.erased;
            self.erase(next, flash)
                .map_err(|()| self.fail(FlashStatus::WriteError))?;
        }
        if bytes == [0xFF, 0xFF] {
            // Erased already (the header slot's padding): nothing to program.
            return Ok(());
        }
        let written = program_half_word(flash, offset, u16::from_le_bytes(bytes));
        let at = offset % PAGE_SIZE;
        if written.is_err() || flash.page(page).get(at..at + 2) != Some(&bytes[..]) {
            return Err(self.fail(FlashStatus::WriteError));
        }
        Ok(())
    }

    /// The last segment arrived: checks that the stream is complete and the CRC of the flash
    /// content, then programs the mark and reads it back.
    pub fn finish(&mut self, flash: &mut impl Flash) -> Result<(), SdoAbort> {
        if !self.streaming {
            self.status = FlashStatus::NotCleared;
            return Err(SdoAbort::DeviceState);
        }
        let Some(header) = self.header else {
            return Err(self.fail(FlashStatus::FormatError));
        };
        let len = header.image_len();
        if self.received != HEADER_SLOT + len {
            return Err(self.fail(FlashStatus::FormatError));
        }
        if let Some(low) = self.carry.take() {
            // An odd length: the last byte with an erased one.
            self.put(self.received - 1, [low, 0xFF], flash)?;
        }
        let sp = read_word(flash, HEADER_SLOT);
        let reset = read_word(flash, HEADER_SLOT + 4);
        if flash_crc(&*flash, HEADER_SLOT, len) != header.crc
            || !vector_table_ok(sp, reset, header.length)
        {
            return Err(self.fail(FlashStatus::FormatError));
        }
        // The mark, last: low half-word, then high.
        let [m0, m1, m2, m3] = MAGIC.to_le_bytes();
        self.put(0, [m0, m1], flash)?;
        self.put(2, [m2, m3], flash)?;
        if read_word(flash, 0) != MAGIC {
            return Err(self.fail(FlashStatus::WriteError));
        }
        self.streaming = false;
        self.control = Control::Stopped;
        self.status = FlashStatus::Ok;
        self.software_id = header.crc;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boot::MAX_TRIAL_STARTS;

    /// `ALL` holds every code once, in order, each with a meaning of one line.
    #[test]
    fn every_flash_status_is_listed_once_with_its_meaning() {
        for status in FlashStatus::ALL {
            // A new variant fails to compile here until it is listed in `ALL` too.
            match status {
                FlashStatus::Ok
                | FlashStatus::NoValidProgram
                | FlashStatus::FormatUnknown
                | FlashStatus::FormatError
                | FlashStatus::NotCleared
                | FlashStatus::WriteError
                | FlashStatus::AddressError
                | FlashStatus::TrialFailed => {}
            }
            let meaning = status.meaning();
            assert!(!meaning.is_empty() && !meaning.contains('\n'), "{status:?}");
            assert!(meaning.len() < 200 && !meaning.contains("  "), "{status:?}");
        }
        assert_eq!(FlashStatus::ALL.len(), 8);
        let codes = FlashStatus::ALL.map(|s| s as u8);
        assert!(codes.windows(2).all(|w| w[0] < w[1]), "{codes:?}");
        assert!(codes.iter().all(|&c| u32::from(c) <= FLASH_CODE_MASK));
        for status in FlashStatus::ALL {
            let word = (status as u32) << FLASH_CODE_SHIFT | FLASH_IN_PROGRESS;
            assert_eq!((word >> FLASH_CODE_SHIFT) & FLASH_CODE_MASK, status as u32);
        }
        let trial = FlashStatus::TrialFailed.meaning();
        assert!(trial.contains(&format!("started {MAX_TRIAL_STARTS} times")));
    }
}
