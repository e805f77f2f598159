//! The chip's NOR flash as both images drive it: a region of whole 1 KiB pages (the
//! application's parameter pages, the loader's application slot), read in place, erased a
//! page at a time and programmed by half-words. One trait for both, so that one power-cut
//! model ([`model`], host tests) stands for the flash under every test of either image.
//!
//! The STM32F103's flash (PM0075 2.3): an erase sets every byte of a page to 0xFF; a program
//! writes one half-word, which must read 0xFFFF before, except 0x0000, which the controller
//! programs over any half-word (the parameter pages' erase ticks rely on it).

/// Bytes in a page of the STM32F103C8 (medium density, RM0008 3.3.3).
pub const PAGE_SIZE: usize = 1024;

/// A failed erase or program.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlashError {
    /// The erase failed or did not read back as erased.
    Erase,
    /// Programming failed or did not read back as written.
    Program,
    /// The flash controller would not unlock, or the region is read-only here.
    Controller,
    /// Outside the region, or not half-word aligned.
    Page,
}

/// A region of whole flash pages; `page` counts from the region's first.
pub trait Flash {
    /// Page `page` as it reads now: [`PAGE_SIZE`] bytes (empty for a page outside the
    /// region).
    fn page(&self, page: usize) -> &[u8];
    /// Erases page `page`: every byte reads 0xFF after success.
    fn erase(&mut self, page: usize) -> Result<(), FlashError>;
    /// Programs `bytes` (even length) at the even `offset` of page `page`, half-word by
    /// half-word: into erased half-words, or 0x0000 over any (the caller checks).
    fn program(&mut self, page: usize, offset: usize, bytes: &[u8]) -> Result<(), FlashError>;
}

/// Copies the bytes of `flash` from region offset `offset` into `buf`: 0xFF past the
/// region's end. (A function over `dyn Flash`, not a provided method: the loader has two
/// kinds of region, and one copy of this in its 12 KiB.)
pub fn read(flash: &dyn Flash, offset: usize, buf: &mut [u8]) {
    let mut done = 0;
    while done < buf.len() {
        let at = offset + done;
        let page = flash.page(at / PAGE_SIZE);
        let start = at % PAGE_SIZE;
        let rest = &mut buf[done..];
        let n = page.len().saturating_sub(start).min(rest.len());
        if n == 0 {
            rest.fill(0xFF);
            return;
        }
        rest[..n].copy_from_slice(&page[start..start + n]);
        done += n;
    }
}

/// Programs the half-word `value` (little-endian) at the even region offset `offset`.
pub fn program_half_word(
    flash: &mut (impl Flash + ?Sized),
    offset: usize,
    value: u16,
) -> Result<(), FlashError> {
    if !offset.is_multiple_of(2) {
        return Err(FlashError::Page);
    }
    flash.program(offset / PAGE_SIZE, offset % PAGE_SIZE, &value.to_le_bytes())
}

// Its own tests run with the crate's, whatever the features.
#[cfg(any(test, feature = "model"))]
pub mod model;

/// A region of the chip's flash, written through its controller with the HAL's writer (it
/// unlocks with the two keys, erases a page or programs half-words, polls BSY, checks the
/// error flags, reads back what it wrote, and locks again on every path: RM0008, "Flash
/// memory programming").
#[cfg(target_os = "none")]
pub struct Region {
    parts: stm32f1xx_hal::flash::Parts,
    /// The region's first byte, from the start of flash.
    offset: u32,
    pages: usize,
}

#[cfg(target_os = "none")]
impl Region {
    /// `pages` pages from the absolute address `origin` (page-aligned, inside the 64 KiB
    /// part), over the flash controller (after the clock set-up used its ACR).
    pub const fn new(parts: stm32f1xx_hal::flash::Parts, origin: u32, pages: usize) -> Self {
        let offset = region_offset(origin, pages);
        Self {
            parts,
            offset,
            pages,
        }
    }

    /// Gives the flash controller back.
    pub fn free(self) -> stm32f1xx_hal::flash::Parts {
        self.parts
    }

    /// The offset from the start of flash of `page`, if it is the region's.
    fn page_offset(&self, page: usize) -> Result<u32, FlashError> {
        if page >= self.pages {
            return Err(FlashError::Page);
        }
        // Inside the 64 KiB part (checked in `new`): no overflow.
        Ok(self.offset + (page * PAGE_SIZE) as u32)
    }

    fn writer(&mut self) -> stm32f1xx_hal::flash::FlashWriter<'_> {
        use stm32f1xx_hal::flash::{FlashSize, SectorSize};
        self.parts.writer(SectorSize::Sz1K, FlashSize::Sz64K)
    }
}

/// The offset of a region of `pages` pages at the absolute address `origin` from the start
/// of flash; a region not page-aligned or not inside the 64 KiB part fails the build (the
/// constructors are `const`) or panics.
#[cfg(target_os = "none")]
const fn region_offset(origin: u32, pages: usize) -> u32 {
    let offset = origin - stm32f1xx_hal::flash::FLASH_START;
    assert!((offset as usize).is_multiple_of(PAGE_SIZE));
    assert!(offset as usize + pages * PAGE_SIZE <= 64 * 1024);
    offset
}

#[cfg(target_os = "none")]
fn controller_or(error: stm32f1xx_hal::flash::Error, otherwise: FlashError) -> FlashError {
    use stm32f1xx_hal::flash::Error;
    match error {
        Error::UnlockError | Error::LockError => FlashError::Controller,
        _ => otherwise,
    }
}

#[cfg(target_os = "none")]
impl Flash for Region {
    fn page(&self, page: usize) -> &[u8] {
        let Ok(offset) = self.page_offset(page) else {
            return &[];
        };
        // A read of memory, not of a register: the HAL's `FlashWriter::read` gives the same
        // slice but borrows the controller mutably, which a shared read does not need.
        // SAFETY: the page lies inside the 64 KiB part (checked in `new` and above): mapped
        // flash, always readable. It changes only through the writer, which needs
        // `&mut self`, so not while this borrow lives.
        unsafe {
            core::slice::from_raw_parts(
                (stm32f1xx_hal::flash::FLASH_START + offset) as *const u8,
                PAGE_SIZE,
            )
        }
    }

    fn erase(&mut self, page: usize) -> Result<(), FlashError> {
        let offset = self.page_offset(page)?;
        self.writer()
            .page_erase(offset)
            .map_err(|e| controller_or(e, FlashError::Erase))
    }

    fn program(&mut self, page: usize, offset: usize, bytes: &[u8]) -> Result<(), FlashError> {
        let start = self.page_offset(page)?;
        if offset > PAGE_SIZE || bytes.len() > PAGE_SIZE - offset {
            return Err(FlashError::Page);
        }
        // `offset` is at most PAGE_SIZE: no overflow.
        self.writer()
            .write(start + offset as u32, bytes)
            .map_err(|e| controller_or(e, FlashError::Program))
    }
}

/// A region of the chip's flash read in place, never written (erase and program fail with
/// [`FlashError::Controller`]): what an image reads of flash it does not own, or before it
/// took the flash controller.
#[cfg(target_os = "none")]
pub struct Mapped {
    origin: u32,
    pages: usize,
}

#[cfg(target_os = "none")]
impl Mapped {
    /// `pages` pages from the absolute address `origin` (page-aligned, inside the 64 KiB
    /// part).
    pub const fn new(origin: u32, pages: usize) -> Self {
        region_offset(origin, pages);
        Self { origin, pages }
    }
}

#[cfg(target_os = "none")]
impl Flash for Mapped {
    fn page(&self, page: usize) -> &[u8] {
        if page >= self.pages {
            return &[];
        }
        // SAFETY: the page lies inside the 64 KiB part (checked in `new` and above): mapped
        // flash, always readable; a write to it through the controller completes before the
        // writer returns, so no read here sees one half done.
        unsafe {
            core::slice::from_raw_parts(
                (self.origin as usize + page * PAGE_SIZE) as *const u8,
                PAGE_SIZE,
            )
        }
    }

    fn erase(&mut self, _page: usize) -> Result<(), FlashError> {
        Err(FlashError::Controller)
    }

    fn program(&mut self, _page: usize, _offset: usize, _bytes: &[u8]) -> Result<(), FlashError> {
        Err(FlashError::Controller)
    }
}
