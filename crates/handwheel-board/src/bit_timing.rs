//! `CAN_BTR` for each bit-rate code at this board's bxCAN clock ([`APB1_HZ`]).

use crate::clocks::APB1_HZ;

/// `CAN_BTR` timing bits by bit-rate code (`handwheel_core::BitRate::code`).
pub const BTR_TABLE: [u32; 8] = handwheel_core::btr_table(APB1_HZ);

/// `CAN_BTR` for `code`; an unknown code gets code 0's (1 Mbit/s).
#[must_use]
pub const fn btr(code: u8) -> u32 {
    if (code as usize) < BTR_TABLE.len() {
        BTR_TABLE[code as usize]
    } else {
        BTR_TABLE[0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bit rate a `CAN_BTR` value gives at `APB1_HZ` (RM0008 24.7.7: BRP + 1 clocks per
    /// quantum, 1 + TS1 + 1 + TS2 + 1 quanta per bit).
    fn bit_rate(btr: u32) -> u32 {
        let brp = (btr & 0x3FF) + 1;
        let ts1 = (btr >> 16 & 0xF) + 1;
        let ts2 = (btr >> 20 & 0x7) + 1;
        APB1_HZ / (brp * (1 + ts1 + ts2))
    }

    #[test]
    fn each_code_gives_its_bit_rate_at_36_mhz() {
        // The value the emulated board reports at 1 Mbit/s (BRP 2, 18 quanta).
        assert_eq!(btr(0), 0x001E_0001);
        assert_eq!(bit_rate(btr(0)), 1_000_000);
        assert_eq!(bit_rate(btr(4)), 125_000);
        for rate in handwheel_core::BitRate::ALL {
            assert_eq!(
                bit_rate(btr(rate.code())),
                rate.bits_per_second(),
                "{rate:?}"
            );
        }
        assert_eq!(btr(9), btr(0), "an unknown code: 1 Mbit/s");
    }
}
