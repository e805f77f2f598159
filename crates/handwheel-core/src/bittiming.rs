//! bxCAN bit timing for the CiA 301 bit-rate table.
//!
//! A bit is `1 + TS1 + TS2` time quanta of `prescaler / f_APB1`; the sample point sits after
//! `1 + TS1` quanta. bxCAN allows a prescaler of 1..=1024, TS1 of 1..=16 and TS2 of 1..=8
//! quanta. The search below keeps only settings that hit the bit rate exactly (any error
//! adds to the oscillator tolerance budget of every node on the bus), with at least 8 quanta
//! per bit (CiA 301), and picks the sample point closest to 87.5 %, preferring more quanta
//! per bit on a tie for a finer resynchronisation grid.

/// The bit rates of the CiA 301 table that this device offers (and its DIP switch selects).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum BitRate {
    /// 1 Mbit/s (the default).
    #[default]
    Kbit1000,
    /// 800 kbit/s.
    Kbit800,
    /// 500 kbit/s.
    Kbit500,
    /// 250 kbit/s.
    Kbit250,
    /// 125 kbit/s.
    Kbit125,
    /// 50 kbit/s.
    Kbit50,
    /// 20 kbit/s.
    Kbit20,
    /// 10 kbit/s.
    Kbit10,
}

impl BitRate {
    /// All rates, fastest first (the order of the DIP switch code).
    pub const ALL: [BitRate; 8] = [
        Self::Kbit1000,
        Self::Kbit800,
        Self::Kbit500,
        Self::Kbit250,
        Self::Kbit125,
        Self::Kbit50,
        Self::Kbit20,
        Self::Kbit10,
    ];

    /// The rate in bit/s.
    pub const fn bits_per_second(self) -> u32 {
        1000 * self.kbit_per_second()
    }

    /// The rate in kbit/s.
    pub const fn kbit_per_second(self) -> u32 {
        match self {
            Self::Kbit1000 => 1000,
            Self::Kbit800 => 800,
            Self::Kbit500 => 500,
            Self::Kbit250 => 250,
            Self::Kbit125 => 125,
            Self::Kbit50 => 50,
            Self::Kbit20 => 20,
            Self::Kbit10 => 10,
        }
    }

    /// From a 3-bit code (0 = 1 Mbit/s .. 7 = 10 kbit/s); higher bits are ignored.
    pub const fn from_code(code: u8) -> Self {
        Self::ALL[(code & 0b111) as usize]
    }

    /// The 3-bit code of this rate.
    pub const fn code(self) -> u8 {
        self as u8
    }
}

// LSS (CiA 305) names a rate by its index in CiA 301's bit-timing table (0-8, 5 = 100 kbit/s,
// which this device does not offer); the DIP code is the index into [`BitRate::ALL`].

/// The LSS bit-timing table indices the firmware supports (bit `i` for index `i`): exactly
/// those [`bit_rate_from_lss`] maps to a rate, so all of 0-8 but 5 (100 kbit/s).
pub const LSS_BIT_TIMINGS: u16 = {
    let mut mask = 0u16;
    let mut index = 0;
    while index < 16 {
        if bit_rate_from_lss(index).is_some() {
            mask |= 1 << index;
        }
        index += 1;
    }
    mask
};

/// The CiA 301 / 305 bit-timing table index of `rate`.
pub const fn lss_bit_timing(rate: BitRate) -> u8 {
    match rate.code() {
        code @ 0..=4 => code,
        code => code + 1,
    }
}

/// The bit rate of CiA 301 / 305 bit-timing table index `index`; `None` for 5 (100 kbit/s)
/// and indices beyond the table.
pub const fn bit_rate_from_lss(index: u8) -> Option<BitRate> {
    match index {
        0..=4 => Some(BitRate::from_code(index)),
        6..=8 => Some(BitRate::from_code(index - 1)),
        _ => None,
    }
}

/// Why a bit rate cannot be configured.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BitTimingError {
    /// No prescaler and segment split divides the clock into this rate exactly.
    NotExact,
    /// Zero bit rate or zero clock.
    Zero,
    /// Above the 1 Mbit/s of classic CAN.
    AboveCanMaximum,
}

/// A validated bxCAN bit timing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BitTiming {
    prescaler: u16,
    ts1: u8,
    ts2: u8,
    sjw: u8,
}

const MAX_BITRATE: u32 = 1_000_000;
const MIN_QUANTA: u32 = 8;
const MAX_QUANTA: u32 = 1 + 16 + 8;
const TARGET_SAMPLE_PERMILLE: u32 = 875;

impl BitTiming {
    /// The timing for `bitrate` from an APB1 clock of `clock_hz`.
    pub const fn for_bitrate(clock_hz: u32, bitrate: u32) -> Result<Self, BitTimingError> {
        if clock_hz == 0 || bitrate == 0 {
            return Err(BitTimingError::Zero);
        }
        if bitrate > MAX_BITRATE {
            return Err(BitTimingError::AboveCanMaximum);
        }
        let mut best: Option<(BitTiming, u32)> = None;
        let mut quanta = MAX_QUANTA;
        while quanta >= MIN_QUANTA {
            let per_bit = bitrate as u64 * quanta as u64;
            if (clock_hz as u64).is_multiple_of(per_bit) {
                let prescaler = (clock_hz as u64) / per_bit;
                if prescaler >= 1 && prescaler <= 1024 {
                    if let Some(timing) = Self::split(prescaler as u16, quanta) {
                        let error = timing
                            .sample_point_permille()
                            .abs_diff(TARGET_SAMPLE_PERMILLE);
                        // Strictly better only: on a tie the larger quanta count, seen first, stays.
                        let better = match best {
                            None => true,
                            Some((_, best_error)) => error < best_error,
                        };
                        if better {
                            best = Some((timing, error));
                        }
                    }
                }
            }
            quanta -= 1;
        }
        match best {
            Some((timing, _)) => Ok(timing),
            None => Err(BitTimingError::NotExact),
        }
    }

    /// The TS1/TS2 split of `quanta` with the sample point nearest 87.5 %.
    const fn split(prescaler: u16, quanta: u32) -> Option<Self> {
        // TS2 = quanta x 12.5 %, rounded to nearest, within bxCAN's 1..=8.
        let mut ts2 = (quanta + 4) / 8;
        if ts2 < 1 {
            ts2 = 1;
        }
        if ts2 > 8 {
            ts2 = 8;
        }
        let ts1 = quanta - 1 - ts2;
        if ts1 < 1 || ts1 > 16 {
            return None;
        }
        // SJW = 1 quantum: the common choice for crystal-clocked nodes; it keeps TS2 >= SJW
        // for every split above.
        Some(Self {
            prescaler,
            ts1: ts1 as u8,
            ts2: ts2 as u8,
            sjw: 1,
        })
    }

    /// The value of the bxCAN `CAN_BTR` register (mode bits LBKM/SILM clear).
    pub const fn btr(&self) -> u32 {
        ((self.sjw as u32 - 1) << 24)
            | ((self.ts2 as u32 - 1) << 20)
            | ((self.ts1 as u32 - 1) << 16)
            | (self.prescaler as u32 - 1)
    }

    /// Baud rate prescaler (1..=1024).
    pub const fn prescaler(&self) -> u16 {
        self.prescaler
    }

    /// Time segment 1 in quanta (propagation + phase 1).
    pub const fn ts1(&self) -> u8 {
        self.ts1
    }

    /// Time segment 2 in quanta (phase 2).
    pub const fn ts2(&self) -> u8 {
        self.ts2
    }

    /// Resynchronisation jump width in quanta.
    pub const fn sjw(&self) -> u8 {
        self.sjw
    }

    /// Quanta per bit.
    pub const fn quanta(&self) -> u32 {
        1 + self.ts1 as u32 + self.ts2 as u32
    }

    /// Sample point in per mille of the bit, rounded down.
    pub const fn sample_point_permille(&self) -> u32 {
        (1 + self.ts1 as u32) * 1000 / self.quanta()
    }
}

/// `CAN_BTR` timing bits for every rate of [`BitRate::ALL`], by code, at the bxCAN clock
/// `clock_hz`; the one table the application and the resident loader both program.
///
/// Meant for a `const`: evaluated at compile time, the build fails if a rate has no exact
/// timing at that clock, and the image carries no 64-bit division.
pub const fn btr_table(clock_hz: u32) -> [u32; 8] {
    let mut table = [0; 8];
    let mut code = 0;
    while code < 8 {
        let rate = BitRate::ALL[code];
        table[code] = match BitTiming::for_bitrate(clock_hz, rate.bits_per_second()) {
            Ok(timing) => timing.btr(),
            Err(_) => panic!("a table bit rate has no exact bxCAN timing at this clock"),
        };
        code += 1;
    }
    table
}

#[cfg(test)]
mod tests {
    use super::*;

    const APB1: u32 = 36_000_000;

    #[test]
    fn the_table_is_each_rates_timing_by_code() {
        const TABLE: [u32; 8] = btr_table(APB1);
        for rate in BitRate::ALL {
            let timing = BitTiming::for_bitrate(APB1, rate.bits_per_second()).unwrap();
            assert_eq!(TABLE[usize::from(rate.code())], timing.btr(), "{rate:?}");
        }
        assert_eq!(
            TABLE[0], 0x001E_0001,
            "1 Mbit/s: 2 x 18 quanta, 16 before the sample"
        );
    }

    #[test]
    fn every_table_rate_is_exact_with_sample_point_in_cia_window() {
        for rate in BitRate::ALL {
            let t = BitTiming::for_bitrate(APB1, rate.bits_per_second()).unwrap();
            let achieved = APB1 / (u32::from(t.prescaler()) * t.quanta());
            assert_eq!(achieved * u32::from(t.prescaler()) * t.quanta(), APB1);
            assert_eq!(achieved, rate.bits_per_second(), "{rate:?}");
            let sp = t.sample_point_permille();
            assert!((850..=900).contains(&sp), "{rate:?}: {sp}");
            assert!(t.quanta() >= 8);
        }
    }

    #[test]
    fn worked_values() {
        // 1 Mbit/s: 36 quanta at prescaler 1 is too many; 2 x 18 gives 16/18 = 88.8 %
        // (3 x 12 would give 83.3 % or 91.6 %).
        let t = BitTiming::for_bitrate(APB1, 1_000_000).unwrap();
        assert_eq!((t.prescaler(), t.ts1(), t.ts2()), (2, 15, 2));
        assert_eq!(t.btr(), 0x001E_0001);
        // 800 kbit/s: 45 = 3 x 15, 13/15 = 86.6 %.
        let t = BitTiming::for_bitrate(APB1, 800_000).unwrap();
        assert_eq!((t.prescaler(), t.ts1(), t.ts2()), (3, 12, 2));
        // 500 kbit/s: 72 quanta-prescaler products; 24 quanta would need TS1 = 20 > 16, so
        // 9 x 8 with 7/8 = 87.5 % exactly beats 4 x 18 at 88.8 %.
        let t = BitTiming::for_bitrate(APB1, 500_000).unwrap();
        assert_eq!((t.prescaler(), t.ts1(), t.ts2()), (9, 6, 1));
        assert_eq!(t.sample_point_permille(), 875);
        // 250 and 125 kbit/s: 16 quanta, 14/16 = 87.5 %.
        let t = BitTiming::for_bitrate(APB1, 250_000).unwrap();
        assert_eq!((t.prescaler(), t.ts1(), t.ts2()), (9, 13, 2));
        let t = BitTiming::for_bitrate(APB1, 125_000).unwrap();
        assert_eq!((t.prescaler(), t.ts1(), t.ts2()), (18, 13, 2));
        assert_eq!(t.btr(), (1 << 20) | (12 << 16) | 17);
    }

    #[test]
    fn inexact_rates_are_rejected() {
        assert_eq!(
            BitTiming::for_bitrate(APB1, 83_333),
            Err(BitTimingError::NotExact)
        );
        // 36 MHz divides into 2 Mbit/s exactly, but classic CAN stops at 1 Mbit/s.
        assert_eq!(
            BitTiming::for_bitrate(APB1, 2_000_000),
            Err(BitTimingError::AboveCanMaximum)
        );
        // 36 MHz / 7 kbit/s is not an integer number of quanta for any prescaler.
        assert_eq!(
            BitTiming::for_bitrate(APB1, 7_000),
            Err(BitTimingError::NotExact)
        );
        assert_eq!(BitTiming::for_bitrate(APB1, 0), Err(BitTimingError::Zero));
        assert_eq!(BitTiming::for_bitrate(0, 1000), Err(BitTimingError::Zero));
    }

    #[test]
    fn codes_round_trip() {
        for (i, rate) in BitRate::ALL.into_iter().enumerate() {
            assert_eq!(rate.code(), i as u8);
            assert_eq!(BitRate::from_code(rate.code()), rate);
        }
        assert_eq!(BitRate::from_code(0b1000), BitRate::Kbit1000);
    }

    #[test]
    fn btr_fields_are_one_less_than_the_values() {
        let t = BitTiming::for_bitrate(APB1, 10_000).unwrap();
        let btr = t.btr();
        assert_eq!((btr & 0x3FF) + 1, u32::from(t.prescaler()));
        assert_eq!(((btr >> 16) & 0xF) + 1, u32::from(t.ts1()));
        assert_eq!(((btr >> 20) & 0x7) + 1, u32::from(t.ts2()));
        assert_eq!(((btr >> 24) & 0x3) + 1, u32::from(t.sjw()));
        assert_eq!(btr & 0xC000_0000, 0, "no loopback or silent mode");
    }
}
