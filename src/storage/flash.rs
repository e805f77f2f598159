//! The parameter page in flash: the last 1 KiB page of the STM32F103C8, erased and
//! programmed for `handwheel_device::page`, which decides what to write and when.
//!
//! Erase and program go straight to the flash controller's registers (RM0008, "Flash
//! memory programming"): unlock with the two keys, page erase (PER, AR, STRT), half-word
//! programming (PG), BSY polled after each step, errors from SR, every half-word and the
//! erased page read back, and the controller locked again on every path. The HAL's flash
//! writer does the same with generic address checks whose panics would pull `core::fmt`
//! into the image; this page has one fixed address, so there is nothing to check at run
//! time beyond the offsets `program` is given.

use handwheel_device::page::{Flash, FlashError, PAGE_SIZE};

use crate::pac;

/// Start of the main flash memory.
const FLASH_START: u32 = 0x0800_0000;
/// Offset of the parameter page from the start of flash: the last 1 KiB page of the
/// 64 KiB part. `board/memory.x` keeps the linker out of it (its STORAGE region).
pub const PAGE_OFFSET: u32 = 63 * 1024;
/// Absolute address of the parameter page.
pub const PAGE_ADDRESS: u32 = FLASH_START + PAGE_OFFSET;

/// The unlock sequence of FLASH_KEYR.
const KEYS: [u32; 2] = [0x4567_0123, 0xCDEF_89AB];

/// The parameter page, owning the flash controller.
pub struct FlashStorage {
    /// Owned, so that nothing else reaches the flash controller; its registers are used
    /// through [`Unlocked`].
    flash: pac::FLASH,
}

impl FlashStorage {
    /// Takes the flash controller (after the clock setup used its ACR).
    pub fn new(flash: pac::FLASH) -> Self {
        Self { flash }
    }

    /// Gives the flash controller back (tests use it to damage a record on purpose).
    pub fn free(self) -> pac::FLASH {
        self.flash
    }

    // Out of line: erase and program both unlock, inlined copies cost more flash.
    #[inline(never)]
    fn unlock(&mut self) -> Result<Unlocked<'_>, FlashError> {
        // SAFETY: `self.flash` owns the FLASH peripheral (taken once from
        // `pac::Peripherals`), and `Unlocked` borrows `self` mutably, so these are the only
        // live accesses to its registers.
        let regs = unsafe { &*pac::FLASH::ptr() };
        let controller = Unlocked {
            regs,
            _owner: &mut self.flash,
        };
        controller.wait_idle();
        for key in KEYS {
            // SAFETY: writing the documented key sequence only unlocks FLASH_CR; a wrong
            // key would lock it until reset, and these are the right ones, in order.
            regs.keyr().write(|w| unsafe { w.key().bits(key) });
        }
        if regs.cr().read().lock().bit_is_set() {
            return Err(FlashError::Controller);
        }
        Ok(controller)
    }
}

impl Flash for FlashStorage {
    fn page(&self) -> &[u8] {
        // SAFETY: PAGE_ADDRESS..+PAGE_SIZE is the last page of the 64 KiB flash: mapped,
        // readable, and kept out of every linker section by memory.x. It only changes
        // through `Unlocked`, which needs `&mut self`, so not while this borrow lives.
        unsafe { core::slice::from_raw_parts(PAGE_ADDRESS as *const u8, PAGE_SIZE) }
    }

    fn erase(&mut self) -> Result<(), FlashError> {
        self.unlock()?.erase_page()
    }

    fn program(&mut self, offset: usize, bytes: &[u8]) -> Result<(), FlashError> {
        self.unlock()?.program(offset, bytes)
    }
}

/// The flash controller between unlock and lock; dropping it locks it again.
struct Unlocked<'a> {
    regs: &'a pac::flash::RegisterBlock,
    _owner: &'a mut pac::FLASH,
}

impl Unlocked<'_> {
    fn wait_idle(&self) {
        while self.regs.sr().read().bsy().bit_is_set() {}
    }

    /// Waits for the operation to end; `true` when it reported no error. Clears the
    /// end-of-operation and error flags (write 1 to clear) for the next one.
    fn finish(&self) -> bool {
        // BSY rises one cycle after the start (STM32F10x errata, "Flash BSY"): look later.
        cortex_m::asm::nop();
        self.wait_idle();
        let sr = self.regs.sr().read();
        let failed = sr.pgerr().bit_is_set() || sr.wrprterr().bit_is_set();
        self.regs
            .sr()
            .write(|w| w.eop().set_bit().pgerr().set_bit().wrprterr().set_bit());
        !failed
    }

    fn erase_page(&mut self) -> Result<(), FlashError> {
        self.regs.cr().modify(|_, w| w.per().set_bit());
        // SAFETY: the page address is a fixed, valid page of this part; with PER set, the
        // STRT below erases that page and nothing else.
        self.regs
            .ar()
            .write(|w| unsafe { w.far().bits(PAGE_ADDRESS) });
        self.regs.cr().modify(|_, w| w.strt().set_bit());
        let ok = self.finish();
        self.regs.cr().modify(|_, w| w.per().clear_bit());
        let base = PAGE_ADDRESS as *const u32;
        let erased = (0..PAGE_SIZE / 4).all(|word| {
            // SAFETY: inside the parameter page (see `FlashStorage::page`), word-aligned.
            unsafe { core::ptr::read_volatile(base.add(word)) == u32::MAX }
        });
        if ok && erased {
            Ok(())
        } else {
            Err(FlashError::Erase)
        }
    }

    /// Programs `bytes` (half-words; an odd last byte is not written) at `offset` of the
    /// page; fails without writing past the page's end.
    fn program(&mut self, offset: usize, bytes: &[u8]) -> Result<(), FlashError> {
        if !offset.is_multiple_of(2) || offset > PAGE_SIZE || bytes.len() > PAGE_SIZE - offset {
            return Err(FlashError::Program);
        }
        let base = (PAGE_ADDRESS as usize + offset) as *mut u16;
        self.regs.cr().modify(|_, w| w.pg().set_bit());
        let result = bytes.chunks_exact(2).enumerate().try_for_each(|(i, pair)| {
            let half_word = u16::from_le_bytes([pair[0], pair[1]]);
            let at = base.wrapping_add(i);
            // SAFETY: `offset` is even and `offset + bytes.len()` within the page (checked
            // above), so `at` is an aligned half-word of the parameter page; with PG set the
            // controller turns this store into a program operation. `&mut self` means no
            // reference into the page is alive.
            unsafe { core::ptr::write_volatile(at, half_word) };
            let ok = self.finish();
            // SAFETY: as above; a plain read of the programmed half-word.
            let written = ok && unsafe { core::ptr::read_volatile(at) } == half_word;
            if written {
                Ok(())
            } else {
                Err(FlashError::Program)
            }
        });
        self.regs.cr().modify(|_, w| w.pg().clear_bit());
        result
    }
}

impl Drop for Unlocked<'_> {
    fn drop(&mut self) {
        self.regs.cr().modify(|_, w| w.lock().set_bit());
    }
}
