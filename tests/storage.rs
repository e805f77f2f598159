//! On-target: the parameter page on the real flash: records round-trip, changed stores append
//! without an erase, unchanged ones write nothing, and an empty or damaged page reads as the
//! last intact record or nothing.
//!
//! This erases the stored parameters of the board it runs on. Run with a board and a probe:
//! `cargo test --target thumbv7m-none-eabi -p handwheel-firmware --test storage`.
#![no_std]
#![no_main]

use defmt_rtt as _;
use handwheel_firmware as _;

#[defmt_test::tests]
mod tests {
    use canopen_slave::{Storage, StorageError};
    use handwheel_core::BitRate;
    use handwheel_firmware::board;
    use handwheel_firmware::pac;
    use handwheel_firmware::storage::{
        parameter_pages, DeviceStorage, Flash, FlashStorage, NodeSettings, BLOB_MAX, PAGE_OFFSET,
    };

    pub struct State {
        pub flash: Option<FlashStorage>,
    }

    #[init]
    fn init() -> State {
        let dp = defmt::unwrap!(pac::Peripherals::take());
        State {
            flash: Some(board::init(dp).storage),
        }
    }

    const SETTINGS: NodeSettings = match NodeSettings::from_parts(42, BitRate::Kbit250.code()) {
        Some(settings) => settings,
        None => panic!("node 42 at 250 kbit/s is valid"),
    };

    #[test]
    fn an_erased_page_reads_as_nothing_stored(state: &mut State) {
        let mut page = super::erased_page(state);
        defmt::assert!(page.stored().is_none());
        defmt::assert_eq!(page.load(&mut [0; 16]), 0);
        super::put_back(state, page);
    }

    #[test]
    fn records_round_trip_and_append_without_an_erase(state: &mut State) {
        let mut page = super::erased_page(state);
        page.set_settings(SETTINGS);
        let blob = [0xA5, 0x00, 0xFF, 0x12, 0x34];
        defmt::unwrap!(page.store(super::now(), &blob));
        let (settings, stored) = defmt::unwrap!(page.stored());
        defmt::assert_eq!(settings, SETTINGS);
        defmt::assert_eq!(stored, &blob[..]);
        // A second, changed record goes after the first: the first is still on the page.
        defmt::unwrap!(page.store(super::now(), &[1, 2]));
        defmt::assert_eq!(defmt::unwrap!(page.stored()).1, &[1, 2]);
        defmt::assert_eq!(&page.flash().page(0)[10..15], &blob[..]);
        // Unchanged: the page stays as it is, byte for byte.
        let before = super::crc(page.flash().page(0));
        defmt::unwrap!(page.store(super::now(), &[1, 2]));
        defmt::assert_eq!(super::crc(page.flash().page(0)), before);
        // A power cycle finds the newest.
        let page = DeviceStorage::new(page.into_flash());
        defmt::assert_eq!(defmt::unwrap!(page.stored()).1, &[1, 2]);
        super::put_back(state, page);
    }

    #[test]
    fn empty_and_largest_blobs_round_trip(state: &mut State) {
        let mut page = super::erased_page(state);
        let max = defmt::unwrap!(NodeSettings::from_parts(127, BitRate::Kbit10.code()));
        page.set_settings(max);
        let mut blob = [0u8; BLOB_MAX];
        for (i, b) in blob.iter_mut().enumerate() {
            *b = i as u8;
        }
        defmt::unwrap!(page.store(super::now(), &blob));
        defmt::assert_eq!(defmt::unwrap!(page.stored()).1, &blob[..]);
        // An oversized blob is refused and the record kept.
        defmt::assert_eq!(
            page.store(super::now(), &[0u8; BLOB_MAX + 1]),
            Err(StorageError::WriteFailed)
        );
        defmt::assert_eq!(defmt::unwrap!(page.stored()).1, &blob[..]);
        // LSS settings with no blob, after "restore defaults" of everything.
        defmt::unwrap!(page.store(super::now(), &[]));
        defmt::assert!(page.stored().is_none());
        defmt::unwrap!(page.store_node(super::now(), 9, 0));
        let (settings, stored) = defmt::unwrap!(page.stored());
        defmt::assert_eq!(settings.node_id_byte(), 9);
        defmt::assert!(stored.is_empty());
        super::put_back(state, page);
    }

    #[test]
    fn a_damaged_record_falls_back_to_the_one_before(state: &mut State) {
        let mut page = super::erased_page(state);
        defmt::unwrap!(page.store(super::now(), &[0x55, 0x55, 0x55, 0x55]));
        // The second record's blob starts at 18 (the first record) + 10 (its header):
        // 0xFFFF there.
        defmt::unwrap!(page.store(super::now(), &[0xFF, 0xFF, 0x55, 0x55]));
        // Program that half-word to 0x0000: allowed without an erase, and the second
        // record's CRC no longer matches.
        let mut flash = page.into_flash().free();
        super::program_half_word(&mut flash, PAGE_OFFSET + 28, 0x0000);
        let page = DeviceStorage::new(parameter_pages(flash));
        defmt::assert_eq!(defmt::unwrap!(page.stored()).1, &[0x55, 0x55, 0x55, 0x55]);
        // Leave the board with nothing stored: it boots with its defaults.
        let mut flash = page.into_flash();
        super::erase_both(&mut flash);
        state.flash = Some(flash);
    }
}

use canopen_slave::Instant;
use handwheel_firmware::storage::DeviceStorage;

/// The pages over the freshly erased flash pages (taken from `state`).
fn erased_page(state: &mut tests::State) -> DeviceStorage {
    let mut flash = defmt::unwrap!(state.flash.take());
    erase_both(&mut flash);
    DeviceStorage::new(flash)
}

/// Erases both parameter pages: records go to the first.
fn erase_both(flash: &mut handwheel_firmware::storage::FlashStorage) {
    use handwheel_firmware::storage::Flash;
    defmt::unwrap!(flash.erase(0));
    defmt::unwrap!(flash.erase(1));
}

/// Gives the flash back to `state` for the next test.
fn put_back(state: &mut tests::State, page: DeviceStorage) {
    state.flash = Some(page.into_flash());
}

/// Engine time: the page's budget is not at stake here (a fresh page has no debt).
fn now() -> Instant {
    Instant::ZERO
}

/// CRC-32 of the page, to compare it before and after.
fn crc(page: &[u8]) -> u32 {
    handwheel_firmware::storage::record::crc32(page)
}

/// Programs one half-word at `offset` from the start of flash with the HAL's writer directly,
/// not through `FlashStorage` (RM0008 3.3.3: unlock, PG, a half-word write, BSY, lock).
fn program_half_word(flash: &mut stm32f1xx_hal::flash::Parts, offset: u32, value: u16) {
    use stm32f1xx_hal::flash::{FlashSize, SectorSize};
    let mut writer = flash.writer(SectorSize::Sz1K, FlashSize::Sz64K);
    // Programming over a half-word that is not erased takes only 0x0000 (PGERR otherwise),
    // so the writer's read-back of other values would fail; 0x0000 reads back.
    defmt::unwrap!(writer.write(offset, &value.to_le_bytes()).ok());
}
