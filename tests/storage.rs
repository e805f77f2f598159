//! On-target: the parameter page round-trips, and an empty or damaged page reads as empty.
//!
//! This erases the stored parameters of the board it runs on. Run with a board and a probe:
//! `cargo test --target thumbv7m-none-eabi -p handwheel-firmware --test storage`.
#![no_std]
#![no_main]

use defmt_rtt as _;
use handwheel_firmware as _;

#[defmt_test::tests]
mod tests {
    use handwheel_core::BitRate;
    use handwheel_firmware::board;
    use handwheel_firmware::pac;
    use handwheel_firmware::storage::{
        FlashStorage, NodeSettings, StoreError, BLOB_MAX, PAGE_OFFSET,
    };

    struct State {
        storage: Option<FlashStorage>,
    }

    #[init]
    fn init() -> State {
        let dp = defmt::unwrap!(pac::Peripherals::take());
        State {
            storage: Some(board::init(dp).storage),
        }
    }

    const SETTINGS: NodeSettings = match NodeSettings::from_parts(42, BitRate::Kbit250.code()) {
        Some(settings) => settings,
        None => panic!("node 42 at 250 kbit/s is valid"),
    };

    #[test]
    fn an_erased_page_reads_as_nothing_stored(state: &mut State) {
        defmt::unwrap!(defmt::unwrap!(state.storage.as_mut()).erase());
        defmt::assert!(defmt::unwrap!(state.storage.as_mut()).load().is_none());
    }

    #[test]
    fn a_record_round_trips(state: &mut State) {
        let blob = [0xA5, 0x00, 0xFF, 0x12, 0x34];
        defmt::unwrap!(defmt::unwrap!(state.storage.as_mut()).store(SETTINGS, &blob));
        let stored = defmt::unwrap!(defmt::unwrap!(state.storage.as_mut()).load());
        defmt::assert_eq!(stored.settings, SETTINGS);
        defmt::assert_eq!(stored.blob, &blob[..]);
    }

    #[test]
    fn empty_and_largest_blobs_round_trip(state: &mut State) {
        let max = defmt::unwrap!(NodeSettings::from_parts(127, BitRate::Kbit10.code()));
        defmt::unwrap!(defmt::unwrap!(state.storage.as_mut()).store(max, &[]));
        let stored = defmt::unwrap!(defmt::unwrap!(state.storage.as_mut()).load());
        defmt::assert_eq!(stored.settings, max);
        defmt::assert!(stored.blob.is_empty());

        let mut blob = [0u8; BLOB_MAX];
        for (i, b) in blob.iter_mut().enumerate() {
            *b = i as u8;
        }
        defmt::unwrap!(defmt::unwrap!(state.storage.as_mut()).store(SETTINGS, &blob));
        defmt::assert_eq!(
            defmt::unwrap!(defmt::unwrap!(state.storage.as_mut()).load()).blob,
            &blob[..]
        );
    }

    #[test]
    fn an_oversized_blob_is_refused_and_the_old_record_kept(state: &mut State) {
        defmt::unwrap!(defmt::unwrap!(state.storage.as_mut()).store(SETTINGS, &[1, 2, 3]));
        let big = [0u8; BLOB_MAX + 1];
        defmt::assert_eq!(
            defmt::unwrap!(state.storage.as_mut()).store(SETTINGS, &big),
            Err(StoreError::TooLarge)
        );
        defmt::assert_eq!(
            defmt::unwrap!(defmt::unwrap!(state.storage.as_mut()).load()).blob,
            &[1, 2, 3]
        );
    }

    #[test]
    fn a_damaged_record_reads_as_nothing_stored(state: &mut State) {
        defmt::unwrap!(
            defmt::unwrap!(state.storage.as_mut()).store(SETTINGS, &[0xFF, 0xFF, 0x55, 0x55])
        );
        // Program the first blob half-word (0xFFFF) to 0x0000: allowed without an erase,
        // and the CRC no longer matches.
        let flash = defmt::unwrap!(state.storage.take()).free();
        super::program_half_word(&flash, PAGE_OFFSET + 8, 0x0000);
        state.storage = Some(FlashStorage::new(flash));
        defmt::assert!(defmt::unwrap!(state.storage.as_mut()).load().is_none());
        // Leave the board with nothing stored: it boots with its defaults.
        defmt::unwrap!(defmt::unwrap!(state.storage.as_mut()).erase());
    }
}

/// Programs one half-word at `offset` from the start of flash, independently of
/// `FlashStorage` (RM0008 3.3.3: unlock, PG, a half-word write, BSY, lock).
fn program_half_word(flash: &handwheel_firmware::pac::FLASH, offset: u32, value: u16) {
    for key in [0x4567_0123, 0xCDEF_89AB] {
        // SAFETY: the documented unlock keys, in order; a wrong one would only lock FLASH_CR
        // until reset.
        flash.keyr().write(|w| unsafe { w.key().bits(key) });
    }
    flash.cr().modify(|_, w| w.pg().set_bit());
    let at = (0x0800_0000 + offset) as *mut u16;
    // SAFETY: `at` is a half-word inside the parameter page, which no code or data uses,
    // and PG is set: the write programs it.
    unsafe { core::ptr::write_volatile(at, value) };
    cortex_m::asm::nop();
    while flash.sr().read().bsy().bit_is_set() {}
    flash
        .cr()
        .modify(|_, w| w.pg().clear_bit().lock().set_bit());
}
