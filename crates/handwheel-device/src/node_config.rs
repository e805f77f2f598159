//! Where the node-ID and bit rate come from: the DIP switch or the stored parameters.
//!
//! The 8-position DIP switch (switch on = line pulled low = bit set):
//!
//! - switches 1-5: node-ID, binary, switch 1 = 1 ... switch 5 = 16 (1..=31);
//! - switches 6-8: bit-rate code, binary, switch 6 = 1 ... switch 8 = 4
//!   (0 = 1000, 1 = 800, 2 = 500, 3 = 250, 4 = 125, 5 = 50, 6 = 20, 7 = 10 kbit/s).
//!
//! All switches off: node-ID and bit rate as stored with 0x1010, or node-ID 16 at 1 Mbit/s
//! when nothing is stored. Node-ID switches off but a bit-rate switch on: the stored (or
//! default) node-ID at the switched bit rate.

use handwheel_core::BitRate;

use crate::record::NodeSettings;

/// Where the settings in force came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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
        node_id => (NodeSettings { node_id, bit_rate }, Source::Dip),
    }
}
