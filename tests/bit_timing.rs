//! On-target: the bit timing the firmware programs is the one the table promises.
//!
//! For every rate of the DIP switch's table, `can::start` must leave `CAN_BTR` holding
//! `handwheel-core`'s timing (computed here at run time on the MCU, against the table the
//! firmware evaluated at compile time). Run with a board and a probe:
//! `cargo test --target thumbv7m-none-eabi -p handwheel-firmware --test bit_timing`.
#![no_std]
#![no_main]

use defmt_rtt as _;
use handwheel_firmware as _;

fn btr_register() -> u32 {
    // SAFETY: a read of CAN_BTR, which has no side effects.
    unsafe { (*handwheel_firmware::pac::CAN::ptr()).btr().read().bits() }
}

#[defmt_test::tests]
mod tests {
    use super::btr_register;
    use canopen_slave::{NodeId, RxFilter};
    use handwheel_core::{BitRate, BitTiming};
    use handwheel_firmware::board::{self, CanInstance, APB1_HZ};
    use handwheel_firmware::can::{self, Mode, BTR_TABLE};
    use handwheel_firmware::pac;

    /// Timing and mode bits of CAN_BTR (SJW, TS2, TS1, BRP; LBKM, SILM).
    const TIMING_MASK: u32 = 0x037F_03FF;
    const LBKM_SILM: u32 = 0xC000_0000;

    struct State {
        can: Option<CanInstance>,
    }

    #[init]
    fn init() -> State {
        let dp = defmt::unwrap!(pac::Peripherals::take());
        State {
            can: Some(board::init(dp).can),
        }
    }

    #[test]
    fn apb1_is_36_mhz() {
        defmt::assert_eq!(APB1_HZ, 36_000_000);
    }

    #[test]
    fn table_matches_the_run_time_search() {
        for rate in BitRate::ALL {
            let timing =
                defmt::unwrap!(BitTiming::for_bitrate(APB1_HZ, rate.bits_per_second()).ok());
            defmt::assert_eq!(BTR_TABLE[usize::from(rate.code())], timing.btr());
        }
    }

    #[test]
    fn worked_values() {
        defmt::assert_eq!(can::btr(BitRate::Kbit1000), 0x001E_0001);
        defmt::assert_eq!(can::btr(BitRate::Kbit125), (1 << 20) | (12 << 16) | 17);
    }

    #[test]
    fn every_rate_lands_in_the_register(state: &mut State) {
        for rate in BitRate::ALL {
            let instance = defmt::unwrap!(state.can.take());
            let node = defmt::unwrap!(NodeId::new(1).ok());
            let started = can::start(instance, rate, RxFilter::new(node), Mode::SilentLoopback);
            let btr = btr_register();
            defmt::info!(
                "{=u32} kbit/s: CAN_BTR {=u32:#010x}",
                rate.kbit_per_second(),
                btr
            );
            defmt::assert_eq!(btr & TIMING_MASK, can::btr(rate));
            defmt::assert_eq!(btr & LBKM_SILM, LBKM_SILM);
            state.can = Some(started.free());
        }
    }
}
