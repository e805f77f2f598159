//! The byte layout of the firmware's parameter page (0x1010 store, LSS store): a log of
//! records, each the whole stored state (node-ID, bit rate, the device's blob) under a CRC-32.
//! Pure functions, no flash access: [`page`](crate::page) decides when to append and erase,
//! the firmware's flash glue erases and programs.
//!
//! ```text
//! offset  size  field
//! 0       4     magic "HWP2" (0x32505748 little-endian)
//! 4       1     node-ID, 1..=127, or 0xFF: unconfigured (LSS, CiA 305); 0: nothing stored
//!               (0x1011 restored the defaults; bit rate and blob length are then 0)
//! 5       1     bit-rate code, 0..=7 (handwheel-core's BitRate table)
//! 6       2     blob length n, little-endian, at most BLOB_MAX
//! 8       2     bits 0-13: wear debt when written, in units of 2^26 us (about 67 s; see
//!               `page`); bits 14-15: the page's generation (which of two pages is newer)
//! 10      n     the device's parameter blob (heartbeat, PDO configuration, ...), opaque here
//! 10+n    4     CRC-32 (IEEE 802.3) of bytes 0..10+n, little-endian
//! ```
//!
//! Each record is padded with 0xFF to an even length because flash is programmed in
//! half-words, and the next record starts right after it. [`scan`] walks them from the start
//! of the page: the last intact one is the stored state. A damaged record (a store cut off
//! by a power loss) is skipped by its length; an unreadable header ends the walk and leaves
//! no room for appending (the next store erases). An erased page (all 0xFF) holds nothing.
//!
//! A *debt mark* is an entry of header and CRC only, node-ID 0, bit-rate code 1, length 0: it
//! stores no state, only a newer debt. Firmware before erase ticks wrote one before an erase
//! of the other page, in slots at the page's end; `page` still reads them there. A record
//! walk reads one as an entry without a record; firmware before marks reads one as a
//! damaged record.

use canopen_slave::NodeId;
use handwheel_core::BitRate;

/// Marks a parameter record; the trailing digit is the layout version.
const MAGIC: [u8; 4] = *b"HWP2";
const HEADER: usize = 10;
const CRC_LEN: usize = 4;
/// Length of a debt mark (header and CRC).
pub const MARK_LEN: usize = HEADER + CRC_LEN;
/// Largest wear debt a record holds (14 bits; the top two bits are the page generation).
pub const DEBT_MAX: u16 = 0x3FFF;
/// Page generations count modulo this.
pub const GENERATIONS: u8 = 4;
/// The node-ID and bit-rate bytes of a debt mark.
const MARK: [u8; 2] = [0, 1];
/// Largest device blob a record holds.
pub const BLOB_MAX: usize = 256;
/// Largest encoded record (even).
pub const RECORD_MAX: usize = HEADER + BLOB_MAX + CRC_LEN;

/// Node-ID and bit rate: what the firmware itself needs before the CAN controller starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
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
        match handwheel_core::bittiming::bit_rate_from_lss(bit_timing) {
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

/// One record as read from the page.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Record<'a> {
    /// Node-ID and bit rate; `None`: nothing stored (0x1011 "restore defaults" of all).
    pub settings: Option<NodeSettings>,
    /// The device's blob (empty when nothing is stored).
    pub blob: &'a [u8],
    /// The wear debt when the record was written, in units of 2^26 us.
    pub debt: u16,
    /// The generation of the page the record was written to (0..=3).
    pub generation: u8,
}

/// The debt field of a record or mark: `debt` (at most [`DEBT_MAX`]: larger is clamped) in
/// bits 0-13, `generation` (modulo [`GENERATIONS`]) in bits 14-15.
pub const fn debt_field(debt: u16, generation: u8) -> u16 {
    let debt = if debt > DEBT_MAX { DEBT_MAX } else { debt };
    debt | ((generation % GENERATIONS) as u16) << 14
}

/// The even length of the record of a `blob_len`-byte blob, or `None` beyond [`BLOB_MAX`].
pub const fn encoded_len(blob_len: usize) -> Option<usize> {
    if blob_len > BLOB_MAX {
        return None;
    }
    Some((HEADER + blob_len + CRC_LEN).next_multiple_of(2))
}

/// Writes the record into the start of `out`; returns its even length, or `None` when the
/// blob is longer than [`BLOB_MAX`]. `settings` `None` (nothing stored) writes node-ID 0, bit
/// rate 0 and `blob` as given (empty, by the page's use). `debt` is the raw debt field
/// ([`debt_field`]). Bytes past the returned length are left as they were; a pad byte that
/// makes the length even is 0xFF.
pub fn encode(
    settings: Option<NodeSettings>,
    blob: &[u8],
    debt: u16,
    out: &mut [u8; RECORD_MAX],
) -> Option<usize> {
    let len = encoded_len(blob.len())?;
    let body = HEADER + blob.len();
    let [node, rate] = settings_bytes(settings);
    out[..4].copy_from_slice(&MAGIC);
    out[4] = node;
    out[5] = rate;
    // `encoded_len` bounded the length by BLOB_MAX.
    out[6..8].copy_from_slice(&(blob.len() as u16).to_le_bytes());
    out[8..HEADER].copy_from_slice(&debt.to_le_bytes());
    out[HEADER..body].copy_from_slice(blob);
    let crc = crc32(&out[..body]);
    out[body..body + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
    if len > body + CRC_LEN {
        // The pad byte reads as erased flash.
        out[len - 1] = 0xFF;
    }
    Some(len)
}

/// A debt mark with the raw debt field `debt` ([`debt_field`]), as firmware before erase ticks
/// wrote them (tests craft such pages with it).
pub fn encode_mark(debt: u16) -> [u8; MARK_LEN] {
    let mut out = [0; MARK_LEN];
    out[..4].copy_from_slice(&MAGIC);
    out[4..6].copy_from_slice(&MARK);
    // Length 0 (bytes 6..8 stay zero).
    out[8..HEADER].copy_from_slice(&debt.to_le_bytes());
    let crc = crc32(&out[..HEADER]);
    out[HEADER..].copy_from_slice(&crc.to_le_bytes());
    out
}

/// The node-ID byte of a "nothing stored" record.
const CLEARED: u8 = 0;

/// The node-ID and bit-rate bytes of a record: equal exactly when the settings are.
pub fn settings_bytes(settings: Option<NodeSettings>) -> [u8; 2] {
    match settings {
        Some(s) => [s.node_id_byte(), s.bit_rate.code()],
        None => [CLEARED, 0],
    }
}

/// An intact entry: a record, or a debt mark (`record` `None`).
#[derive(Clone, Copy)]
struct Entry<'a> {
    record: Option<Record<'a>>,
    debt: u16,
    generation: u8,
}

/// What starts at some offset of the page.
enum Slot<'a> {
    /// Erased flash (or too little room left for a header): the free tail.
    Erased,
    /// An entry of this even length: intact (`Some`) or damaged (`None`).
    Record(Option<Entry<'a>>, usize),
    /// Neither: no record boundary can be trusted from here on.
    Garbage,
}

fn slot(bytes: &[u8]) -> Slot<'_> {
    let Some(header) = bytes.get(..HEADER) else {
        return Slot::Erased;
    };
    if header[..4] == [0xFF; 4] {
        return Slot::Erased;
    }
    if header[..4] != MAGIC {
        return Slot::Garbage;
    }
    let blob_len = usize::from(u16::from_le_bytes([header[6], header[7]]));
    let (Some(len), body) = (encoded_len(blob_len), HEADER + blob_len) else {
        return Slot::Garbage;
    };
    let (Some(data), Some(crc)) = (bytes.get(..body), bytes.get(body..body + CRC_LEN)) else {
        return Slot::Garbage;
    };
    // Outer `None`: impossible settings; `Some(None)`: a mark.
    let settings = match (header[4], header[5], blob_len) {
        (CLEARED, 0, 0) => Some(Some(None)),
        (node, rate, 0) if [node, rate] == MARK => Some(None),
        (node, code, _) => NodeSettings::from_parts(node, code).map(|s| Some(Some(s))),
    };
    let field = u16::from_le_bytes([header[8], header[9]]);
    let (debt, generation) = (field & DEBT_MAX, (field >> 14) as u8);
    let entry = match settings {
        Some(settings) if crc32(data).to_le_bytes() == crc => Some(Entry {
            record: settings.map(|settings| Record {
                settings,
                blob: &bytes[HEADER..body],
                debt,
                generation,
            }),
            debt,
            generation,
        }),
        _ => None,
    };
    Slot::Record(entry, len)
}

/// The debt and page generation of an intact debt mark at the start of `bytes`.
pub fn decode_mark(bytes: &[u8]) -> Option<(u16, u8)> {
    match slot(bytes) {
        Slot::Record(Some(entry), MARK_LEN) if entry.record.is_none() => {
            Some((entry.debt, entry.generation))
        }
        _ => None,
    }
}

/// Reads the record at the start of `bytes`; `None` when there is no intact one.
pub fn decode(bytes: &[u8]) -> Option<Record<'_>> {
    match slot(bytes) {
        Slot::Record(entry, _) => entry.and_then(|e| e.record),
        Slot::Erased | Slot::Garbage => None,
    }
}

/// The page as [`scan`] reads it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Log<'a> {
    /// The last intact record: the stored state (a "nothing stored" record included).
    pub newest: Option<Record<'a>>,
    /// The debt of the last intact entry (record or mark).
    pub debt: Option<u16>,
    /// The page's generation: the last intact entry's.
    pub generation: Option<u8>,
    /// Where the next record may go: the end of the last record walked, or the page's
    /// length when the walk met something unreadable. The bytes from here on may still be
    /// anything: check that they are erased before programming.
    pub free: usize,
}

/// Walks the records from the start of `page`.
pub fn scan(page: &[u8]) -> Log<'_> {
    let mut log = Log {
        newest: None,
        debt: None,
        generation: None,
        free: 0,
    };
    while let Some(rest) = page.get(log.free..) {
        match slot(rest) {
            Slot::Erased => break,
            Slot::Record(entry, len) => {
                if let Some(entry) = entry {
                    if entry.record.is_some() {
                        log.newest = entry.record;
                    }
                    log.debt = Some(entry.debt);
                    log.generation = Some(entry.generation);
                }
                log.free += len;
            }
            Slot::Garbage => {
                log.free = page.len();
                break;
            }
        }
    }
    log
}

/// CRC-32 as in IEEE 802.3 / zlib: `crc32(b"123456789") == 0xCBF4_3926`. The engine's (one
/// implementation for records, serial number and firmware image); a few hundred bytes at boot
/// and on a store are all it sees here.
pub use canopen_slave::crc::crc32;
