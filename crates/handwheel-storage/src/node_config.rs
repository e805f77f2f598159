//! Where the node-ID and bit rate come from: the DIP switch or the stored parameters.
//!
//! The 8-position DIP switch (switch on = line pulled low = bit set):
//!
//! - switches 1-5: node-ID, binary, switch 1 = 1 ... switch 5 = 16 (1..=31);
//! - switches 6-8: bit-rate code, binary, switch 6 = 1 ... switch 8 = 4
//!   (0 = 1000, 1 = 800, 2 = 500, 3 = 250, 4 = 125, 5 = 50, 6 = 20, 7 = 10 kbit/s).
//!
//! All switches off: node-ID and bit rate as stored with 0x1010 or LSS "store
//! configuration" (one record, the same page), or node-ID 16 at 1 Mbit/s when nothing is
//! stored. Node-ID switches off but a bit-rate switch on: the stored (or default) node-ID at
//! the switched bit rate. Any node-ID switch on: the switch wins over a stored node-ID, as
//! over every stored value. A stored node-ID 0xFF (LSS "unconfigured") is used like any
//! stored one: the node then waits for an LSS master.
//!
//! LSS works on top at run time whatever the switch says: a node-ID configured by LSS takes
//! effect at the next NMT reset (communication or node) and lasts until power-off, and a
//! stored one at the next power-on unless the DIP switch overrides it.
//!
//! LSS speaks CiA 301's bit-timing table (index 0-8, 5 = 100 kbit/s); the DIP code and the
//! record use `handwheel-core`'s 8-rate table without 100 kbit/s: [`lss_bit_timing`] and
//! [`bit_rate_from_lss`], which live beside [`BitRate`], convert.

pub use handwheel_core::bittiming::{bit_rate_from_lss, lss_bit_timing, LSS_BIT_TIMINGS};
use handwheel_core::BitRate;

use crate::record::NodeSettings;

/// Where the settings in force came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Source {
    /// Node-ID and bit rate from the DIP switch.
    Dip,
    /// Bit rate from the DIP switch, node-ID stored or default.
    DipBitRate,
    /// Both as stored with 0x1010.
    Stored,
    /// Nothing stored: node-ID 16 at 1 Mbit/s.
    Default,
}

/// The serial number for 0x1018:4 from the MCU's 96-bit unique ID: the CRC-32 of its 12
/// bytes (words in address order, little-endian), so that it spreads over all 32 bits and
/// stays the same for the life of the chip.
pub fn serial_number(unique_id: [u32; 3]) -> u32 {
    let mut bytes = [0; 12];
    for (chunk, word) in bytes.chunks_exact_mut(4).zip(unique_id) {
        chunk.copy_from_slice(&word.to_le_bytes());
    }
    crate::record::crc32(&bytes)
}

/// The node-ID and bit rate in force for DIP reading `dip` (bit `i` = switch `i + 1` on) and
/// the stored settings, if any.
pub fn select(dip: u8, stored: Option<NodeSettings>) -> (NodeSettings, Source) {
    let (fallback, fallback_source) = match stored {
        Some(settings) => (settings, Source::Stored),
        None => (NodeSettings::DEFAULT, Source::Default),
    };
    if dip == 0 {
        return (fallback, fallback_source);
    }
    let bit_rate = BitRate::from_code(dip >> 5);
    match dip & 0x1F {
        0 => (
            NodeSettings {
                node_id: fallback.node_id,
                bit_rate,
            },
            Source::DipBitRate,
        ),
        // 1..=31: always a node-ID.
        switches => (
            NodeSettings {
                node_id: canopen_slave::NodeId::new(switches).ok(),
                bit_rate,
            },
            Source::Dip,
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serial_number_is_the_crc32_of_the_unique_id_bytes() {
        // Values from zlib's crc32 of the same 12 bytes: the emulated board's ID
        // (tools/stm32emu) and the machine benchmark's (bytes 0x31..=0x3C).
        let board = [0x0035_003A, 0x3431_570D, 0x3C35_3239];
        assert_eq!(serial_number(board), 0xCA73_6134);
        let bench = [0x3433_3231, 0x3837_3635, 0x3C3B_3A39];
        assert_eq!(serial_number(bench), 0x4DF4_ABCD);
    }
}
