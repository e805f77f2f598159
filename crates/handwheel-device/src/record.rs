//! The byte layout of the firmware's parameter page (0x1010 store): node-ID, bit rate and
//! the device's blob under a CRC-32. Pure functions, no flash access: the board's flash glue
//! erases and programs, this module decides what the bytes mean.
//!
//! ```text
//! offset  size  field
//! 0       4     magic "HWP1" (0x31505748 little-endian)
//! 4       1     node-ID, 1..=127, or 0xFF: unconfigured (LSS, CiA 305)
//! 5       1     bit-rate code, 0..=7 (handwheel-core's BitRate table)
//! 6       2     blob length n, little-endian, at most BLOB_MAX
//! 8       n     the device's parameter blob (heartbeat, PDO configuration, ...), opaque here
//! 8+n     4     CRC-32 (IEEE 802.3) of bytes 0..8+n, little-endian
//! ```
//!
//! The record is padded with 0xFF to an even length because flash is programmed in
//! half-words. An erased page (all 0xFF) fails the magic check, a half-written or damaged one
//! the CRC; either reads as "nothing stored" and the firmware falls back to its defaults.

use canopen_slave::NodeId;
use handwheel_core::BitRate;

/// Marks a parameter record; the trailing digit is the layout version.
const MAGIC: [u8; 4] = *b"HWP1";
const HEADER: usize = 8;
const CRC_LEN: usize = 4;
/// Largest device blob a record holds.
pub const BLOB_MAX: usize = 256;
/// Largest encoded record (even).
pub const RECORD_MAX: usize = HEADER + BLOB_MAX + CRC_LEN;

/// Node-ID and bit rate: what the firmware itself needs before the CAN controller starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NodeSettings {
    /// CANopen node-ID; `None`: unconfigured, the node waits for an LSS master to give it
    /// one (stored as 0xFF, [`canopen_slave::lss::UNCONFIGURED`]).
    pub node_id: Option<NodeId>,
    /// CAN bit rate.
    pub bit_rate: BitRate,
}

impl NodeSettings {
    /// Node-ID 16 at 1 Mbit/s: the factory setting.
    pub const DEFAULT: Self = Self {
        node_id: match NodeId::new(16) {
            Ok(id) => Some(id),
            Err(_) => panic!("16 is a node-ID"),
        },
        bit_rate: BitRate::Kbit1000,
    };

    /// `None` unless `node_id` is a valid CANopen node-ID (1..=127) or 0xFF (unconfigured)
    /// and `code` a bit-rate code (0..=7).
    pub const fn from_parts(node_id: u8, code: u8) -> Option<Self> {
        let node_id = match NodeId::new(node_id) {
            Ok(id) => Some(id),
            Err(_) if node_id == canopen_slave::lss::UNCONFIGURED => None,
            Err(_) => return None,
        };
        if code > 7 {
            return None;
        }
        Some(Self {
            node_id,
            bit_rate: BitRate::from_code(code),
        })
    }

    /// The node-ID as stored and as LSS reports it: 1..=127, or 0xFF when unconfigured.
    pub const fn node_id_byte(&self) -> u8 {
        match self.node_id {
            Some(id) => id.get(),
            None => canopen_slave::lss::UNCONFIGURED,
        }
    }
}

impl NodeSettings {
    /// What LSS "store configuration" hands over: a node-ID (or 0xFF) and a CiA 301 / 305
    /// bit-timing table index. `None` for an index the firmware cannot run at or a node-ID
    /// a record cannot hold; the LSS answer is then "not supported".
    pub const fn from_lss(node_id: u8, bit_timing: u8) -> Option<Self> {
        match crate::node_config::bit_rate_from_lss(bit_timing) {
            Some(rate) => Self::from_parts(node_id, rate.code()),
            None => None,
        }
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for NodeSettings {
    fn format(&self, f: defmt::Formatter) {
        defmt::write!(
            f,
            "node-ID {=u8} at {=u32} kbit/s",
            self.node_id_byte(),
            self.bit_rate.kbit_per_second()
        );
    }
}

/// Writes the record for `settings` and `blob` into the start of `out`; returns its even
/// length, or `None` when the blob is longer than [`BLOB_MAX`]. Bytes past the returned
/// length are left as they were; a pad byte that makes the length even is 0xFF.
pub fn encode(settings: NodeSettings, blob: &[u8], out: &mut [u8; RECORD_MAX]) -> Option<usize> {
    let blob_len = u16::try_from(blob.len())
        .ok()
        .filter(|&n| usize::from(n) <= BLOB_MAX)?;
    let body = HEADER + blob.len();
    out[..4].copy_from_slice(&MAGIC);
    out[4] = settings.node_id_byte();
    out[5] = settings.bit_rate.code();
    out[6..HEADER].copy_from_slice(&blob_len.to_le_bytes());
    out[HEADER..body].copy_from_slice(blob);
    let crc = crc32(&out[..body]);
    out[body..body + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
    let len = (body + CRC_LEN).next_multiple_of(2);
    if len > body + CRC_LEN {
        // The pad byte reads as erased flash.
        out[len - 1] = 0xFF;
    }
    Some(len)
}

/// Reads a record from the start of `page`: the settings and the device blob, or `None` when
/// the page holds no valid record.
pub fn decode(page: &[u8]) -> Option<(NodeSettings, &[u8])> {
    let header = page.get(..HEADER)?;
    if header[..4] != MAGIC {
        return None;
    }
    let blob_len = usize::from(u16::from_le_bytes([header[6], header[7]]));
    if blob_len > BLOB_MAX {
        return None;
    }
    let body = HEADER + blob_len;
    let stored_crc = page.get(body..body + CRC_LEN)?;
    if crc32(&page[..body]).to_le_bytes() != stored_crc {
        return None;
    }
    let settings = NodeSettings::from_parts(header[4], header[5])?;
    Some((settings, &page[HEADER..body]))
}

/// CRC-32 as in IEEE 802.3 / zlib (reflected, polynomial 0x04C11DB7, init and final XOR
/// 0xFFFFFFFF): `crc32(b"123456789") == 0xCBF4_3926`. Bitwise, to keep the image small; a
/// few hundred bytes at boot and on a store are all it ever sees.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &byte in bytes {
        crc ^= u32::from(byte);
        for _ in 0..8 {
            let lsb = crc & 1;
            crc = (crc >> 1) ^ (0xEDB8_8320 & lsb.wrapping_neg());
        }
    }
    !crc
}
