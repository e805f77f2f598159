//! A region of NOR flash as the STM32F103's behaves, for host tests of either image (the
//! parameter pages, the loader's slot), with at most one power cut: before an operation (it
//! never starts) or inside it (a cut erase leaves a seeded subset of the page's half-words
//! erased and the rest as they were; a cut program clears only a seeded part of the bits it
//! should). It counts operations (every half-word programmed, every page erase), can fail
//! one without a cut (a broken controller), and panics on what the chip's controller would
//! refuse or the firmware must never ask: an access outside the region, a program into a
//! half-word that is neither erased nor being set to 0x0000.
//!
//! The emulated board's flash controller (tools/stm32emu, `periph.Fpec`) has the same model
//! in Python, for the release images.

extern crate std;

use std::vec::Vec;

use super::{Flash, FlashError, PAGE_SIZE};

/// Where power is cut: before flash operation `n` (counted from 0 since power-up; it never
/// starts), or inside it with the seed of what got done.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cut {
    /// Before operation `n`.
    Before(usize),
    /// Inside operation `n`, with a seed.
    Inside(usize, u64),
}

/// splitmix64: the seeded choices of a cut, and of the tests' data.
pub fn mix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A region of whole pages.
#[derive(Clone, Debug)]
pub struct CutFlash {
    /// The region's bytes.
    pub bytes: Vec<u8>,
    /// Operations asked for since power-up (half-word programs and page erases).
    pub ops: usize,
    /// Erases that started (completed or cut inside), over every power-up.
    pub erases: u64,
    /// Half-words programmed completely, over every power-up.
    pub programs: u64,
    /// The operation that fails without a power cut (a broken controller).
    pub fail_at: Option<usize>,
    /// The planned power cut.
    pub cut: Option<Cut>,
    /// Power is off: nothing more happens.
    pub dead: bool,
}

impl CutFlash {
    /// `pages` erased pages.
    pub fn erased(pages: usize) -> Self {
        Self::holding(std::vec![0xFF; pages * PAGE_SIZE])
    }

    /// A region holding `bytes` (whole pages).
    pub fn holding(bytes: Vec<u8>) -> Self {
        assert!(
            bytes.len().is_multiple_of(PAGE_SIZE),
            "a region of whole pages"
        );
        Self {
            bytes,
            ops: 0,
            erases: 0,
            programs: 0,
            fail_at: None,
            cut: None,
            dead: false,
        }
    }

    /// The flash after the power came back: the same bytes, no cut or failure planned,
    /// operations counted anew (erases not).
    pub fn powered_up(&self) -> Self {
        Self {
            erases: self.erases,
            programs: self.programs,
            ..Self::holding(self.bytes.clone())
        }
    }

    /// Pages in the region.
    pub fn pages(&self) -> usize {
        self.bytes.len() / PAGE_SIZE
    }

    /// Starts an operation: `Ok(None)` to do it, `Ok(Some(seed))` to cut inside it, `Err`
    /// when the power is (now) off or the controller fails.
    fn start(&mut self) -> Result<Option<u64>, FlashError> {
        if self.dead {
            return Err(FlashError::Controller);
        }
        let op = self.ops;
        self.ops += 1;
        if self.fail_at == Some(op) {
            return Err(FlashError::Controller);
        }
        match self.cut {
            Some(Cut::Before(n)) if n == op => {
                self.dead = true;
                Err(FlashError::Controller)
            }
            Some(Cut::Inside(n, seed)) if n == op => {
                self.dead = true;
                Ok(Some(seed))
            }
            _ => Ok(None),
        }
    }
}

impl Flash for CutFlash {
    fn page(&self, page: usize) -> &[u8] {
        self.bytes
            .get(page * PAGE_SIZE..(page + 1) * PAGE_SIZE)
            .unwrap_or(&[])
    }

    fn erase(&mut self, page: usize) -> Result<(), FlashError> {
        assert!(page < self.pages(), "erase outside the region: page {page}");
        let cut = self.start()?;
        self.erases += 1;
        let range = page * PAGE_SIZE..(page + 1) * PAGE_SIZE;
        let Some(mut seed) = cut else {
            self.bytes[range].fill(0xFF);
            return Ok(());
        };
        for pair in self.bytes[range].chunks_exact_mut(2) {
            if mix(&mut seed) & 1 == 1 {
                pair.fill(0xFF);
            }
        }
        Err(FlashError::Erase)
    }

    fn program(&mut self, page: usize, offset: usize, bytes: &[u8]) -> Result<(), FlashError> {
        assert!(
            page < self.pages()
                && offset.is_multiple_of(2)
                && bytes.len().is_multiple_of(2)
                && offset + bytes.len() <= PAGE_SIZE,
            "program outside the region or unaligned: page {page}, offset {offset}, {} bytes",
            bytes.len()
        );
        for (i, pair) in bytes.chunks_exact(2).enumerate() {
            if self.dead {
                return Err(FlashError::Controller);
            }
            let at = page * PAGE_SIZE + offset + 2 * i;
            let old = u16::from_le_bytes([self.bytes[at], self.bytes[at + 1]]);
            let new = u16::from_le_bytes([pair[0], pair[1]]);
            assert!(
                old == 0xFFFF || new == 0,
                "programming a half-word that is not erased, at {at}"
            );
            let cut = self.start()?;
            let value = match cut {
                None => new,
                Some(mut seed) => old & !(old & !new & mix(&mut seed) as u16),
            };
            self.bytes[at..at + 2].copy_from_slice(&value.to_le_bytes());
            if cut.is_some() {
                return Err(FlashError::Program);
            }
            self.programs += 1;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::{program_half_word, read};
    use super::*;

    #[test]
    fn an_uncut_region_erases_programs_and_reads_back() {
        let mut flash = CutFlash::erased(2);
        flash.program(1, 4, &[0x34, 0x12, 0x78, 0x56]).unwrap();
        let mut buf = [0; 6];
        read(&flash, PAGE_SIZE + 2, &mut buf);
        assert_eq!(buf, [0xFF, 0xFF, 0x34, 0x12, 0x78, 0x56]);
        program_half_word(&mut flash, PAGE_SIZE + 4, 0).unwrap();
        assert_eq!(
            &flash.page(1)[4..6],
            &[0, 0],
            "0x0000 over a programmed half-word"
        );
        let mut past = [0; 4];
        read(&flash, 2 * PAGE_SIZE - 2, &mut past);
        assert_eq!(past, [0xFF; 4], "0xFF past the region");
        flash.erase(1).unwrap();
        assert!(flash.page(1).iter().all(|&b| b == 0xFF));
        assert_eq!((flash.ops, flash.erases, flash.programs), (4, 1, 3));
    }

    #[test]
    fn a_cut_before_an_operation_leaves_it_undone_and_the_power_off() {
        let mut flash = CutFlash::erased(1);
        flash.cut = Some(Cut::Before(1));
        flash.program(0, 0, &[0, 0, 0, 0]).unwrap_err();
        assert_eq!(&flash.page(0)[..4], &[0, 0, 0xFF, 0xFF]);
        assert_eq!(flash.erase(0), Err(FlashError::Controller), "no power");
        let up = flash.powered_up();
        assert!(!up.dead && up.ops == 0 && up.bytes == flash.bytes);
    }

    #[test]
    fn a_cut_inside_clears_only_bits_it_should_and_erases_part_of_a_page() {
        for seed in 0..32 {
            let mut flash = CutFlash::erased(1);
            flash.cut = Some(Cut::Inside(0, seed));
            assert_eq!(
                program_half_word(&mut flash, 0, 0x1234),
                Err(FlashError::Program)
            );
            let got = u16::from_le_bytes([flash.bytes[0], flash.bytes[1]]);
            assert_eq!(got & 0x1234, 0x1234, "no bit cleared that 0x1234 keeps");

            let mut flash = CutFlash::holding(std::vec![0; PAGE_SIZE]);
            flash.cut = Some(Cut::Inside(0, seed));
            assert_eq!(flash.erase(0), Err(FlashError::Erase));
            let erased = flash.bytes.chunks(2).filter(|p| p == &[0xFF, 0xFF]).count();
            assert!(
                0 < erased && erased < PAGE_SIZE / 2,
                "partly erased: {erased}"
            );
            assert!(flash
                .bytes
                .chunks(2)
                .all(|p| p == [0, 0] || p == [0xFF, 0xFF]));
        }
    }

    #[test]
    #[should_panic(expected = "not erased")]
    fn programming_over_a_programmed_half_word_is_a_bug() {
        let mut flash = CutFlash::erased(1);
        program_half_word(&mut flash, 0, 0x00FF).unwrap();
        let _ = program_half_word(&mut flash, 0, 0x000F);
    }
}
