//! Receive PDOs: communication (0x1400+n) and mapping (0x1600+n) parameters (CiA 301
//! 7.5.2.35-36), and what a receiver keeps between frames: a synchronous PDO's data until
//! the next SYNC, and the deadline of its monitoring (the event timer, sub-index 5).

use crate::abort::SdoAbort;
use crate::cob_id::COB_INVALID;
use crate::frame::MAX_STANDARD_ID;
use crate::mapping::{split_mapping, PdoMapping};
use crate::nmt::NmtState;
use crate::od::{Od, OdEntry, Value};
use crate::time::Instant;

/// Number of receive PDOs.
pub const RPDOS: usize = 1;

/// The size in bytes of dummy mapping object `index` (the data type entries 0x0002..0x0007,
/// INTEGER8..UNSIGNED32, which an RPDO may map to skip bytes), or `None` if it is none. The
/// EDS's `[DummyUsage]` is written from it.
pub const fn dummy_size(index: u16) -> Option<usize> {
    match index {
        0x0002 | 0x0005 => Some(1),
        0x0003 | 0x0006 => Some(2),
        0x0004 | 0x0007 => Some(4),
        _ => None,
    }
}

/// What an RPDO mapping entry writes, with its size in bytes: an application object that
/// is writable and mappable and mapped whole, or nothing for a dummy entry (0x0002..0x0007
/// sub 0, INTEGER8..UNSIGNED32: its bytes are skipped, so that a master can send one frame
/// to several nodes, each mapping only its part).
pub(crate) fn check_rpdo_mapping(
    od: &Od,
    entry: u32,
) -> Result<(Option<&'static OdEntry>, usize), SdoAbort> {
    let (index, sub, bits) = split_mapping(entry);
    if let Some(size) = dummy_size(index) {
        return if sub == 0 && usize::from(bits) == size * 8 {
            Ok((None, size))
        } else {
            Err(SdoAbort::NotMappable)
        };
    }
    let e = od.find(index, sub)?;
    let size = e.data_type().size().ok_or(SdoAbort::NotMappable)?;
    // Only application objects are ever mappable (`Od::new`); said again so that an RPDO
    // can never reach a communication parameter behind its checks.
    let app = matches!(e.value(), Value::App);
    if !app || !e.is_mappable() || !e.access().writable() || usize::from(bits) != size * 8 {
        return Err(SdoAbort::NotMappable);
    }
    Ok((Some(e), size))
}

/// [`check_rpdo_mapping`] as the mapping's write check.
fn check_entry(od: &Od, entry: u32) -> Result<usize, SdoAbort> {
    check_rpdo_mapping(od, entry).map(|(_, size)| size)
}

/// One receive PDO: its parameters and its reception state.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) struct Rpdo {
    cob_id: u32,
    transmission_type: u8,
    event_timer_ms: u16,
    mapping: PdoMapping,
    /// Synchronous types: the newest frame's data since the last SYNC, applied at the next.
    pub(crate) held: Option<[u8; 8]>,
    /// Deadline monitoring: when the missing next frame is a timeout. Armed by each frame
    /// received in Operational; `None` before the first one and after a timeout.
    pub(crate) deadline: Option<Instant>,
    /// The reception error whose EMCY is active (length, refused values), if any.
    pub(crate) fault: Option<u16>,
    /// The deadline passed and no frame came since (EMCY 0x8250 active).
    pub(crate) timed_out: bool,
}

impl Rpdo {
    pub(crate) const fn new() -> Self {
        Self {
            cob_id: COB_INVALID,
            transmission_type: 255,
            event_timer_ms: 0,
            mapping: PdoMapping::new(),
            held: None,
            deadline: None,
            fault: None,
            timed_out: false,
        }
    }

    fn valid(&self) -> bool {
        self.cob_id & COB_INVALID == 0
    }

    /// Whether the PDO is received: valid, with something mapped (a frame of an RPDO that
    /// maps nothing would change nothing, so its identifier is not listened to).
    pub(crate) fn active(&self) -> bool {
        self.valid() && self.mapping.any()
    }

    /// Types 0..=240: the data takes effect at the next SYNC; 254/255 at once.
    pub(crate) fn synchronous(&self) -> bool {
        self.transmission_type <= 240
    }

    /// The raw 0x1400+n:01 entry.
    pub(crate) const fn cob_id(&self) -> u32 {
        self.cob_id
    }

    /// CAN-ID received on.
    pub(crate) fn can_id(&self) -> u16 {
        (self.cob_id & u32::from(MAX_STANDARD_ID)) as u16
    }

    /// The active mapping entries.
    pub(crate) fn mapping(&self) -> &[u32] {
        self.mapping.entries()
    }

    /// Deadline monitoring restarts: the next frame is due within the event timer.
    pub(crate) fn received(&mut self, now: Instant) {
        self.deadline = (self.event_timer_ms != 0).then(|| now.after_ms(self.event_timer_ms));
    }

    /// Reads 0x1400+n.
    pub(crate) fn read_comm(&self, sub: u8) -> Result<u32, SdoAbort> {
        match sub {
            1 => Ok(self.cob_id),
            2 => Ok(self.transmission_type.into()),
            5 => Ok(self.event_timer_ms.into()),
            _ => Err(SdoAbort::NoSubIndex),
        }
    }

    /// Checked write of 0x1400+n. The COB-ID (sub 1) is the engine's to check first, as a
    /// TPDO's. Any change drops held data and stops deadline monitoring until the next frame.
    #[inline]
    pub(crate) fn write_comm(&mut self, sub: u8, v: u32) -> Result<(), SdoAbort> {
        match sub {
            // 241..=253 are reserved (252/253 are RTR-only types, TPDOs only).
            2 if matches!(v, 241..=253) => return Err(SdoAbort::InvalidValue),
            1 | 2 | 5 => {}
            _ => return Err(SdoAbort::NoSubIndex),
        }
        self.set_comm(sub, v);
        self.held = None;
        self.deadline = None;
        Ok(())
    }

    /// Unchecked write of 0x1400+n (defaults, stored parameters).
    pub(crate) fn set_comm(&mut self, sub: u8, v: u32) {
        // Truncations are intended: the table types these sub-indices as U8/U16.
        match sub {
            1 => self.cob_id = v,
            2 => self.transmission_type = v as u8,
            5 => self.event_timer_ms = v as u16,
            _ => {}
        }
    }

    /// Reads 0x1600+n.
    pub(crate) fn read_mapping(&self, sub: u8) -> Result<u32, SdoAbort> {
        self.mapping.read(sub)
    }

    /// Checked write of 0x1600+n ([`PdoMapping::write`]: objects an RPDO may write).
    pub(crate) fn write_mapping(&mut self, sub: u8, v: u32, od: &Od) -> Result<(), SdoAbort> {
        let valid = self.valid();
        self.mapping.write(sub, v, valid, od, check_entry)
    }

    /// Unchecked write of 0x1600+n (defaults, stored parameters).
    pub(crate) fn set_mapping(&mut self, sub: u8, v: u32) {
        self.mapping.set(sub, v);
    }
}

/// NMT state change: outside Operational RPDOs are not received (CiA 301), so held data is
/// dropped and deadline monitoring stops; it starts again with the first frame after the
/// next entry to Operational, not at the entry (the master may start its PDOs later).
pub(crate) fn on_nmt_state(rpdos: &mut [Rpdo; RPDOS], next: NmtState) {
    if next != NmtState::Operational {
        for r in rpdos {
            r.held = None;
            r.deadline = None;
        }
    }
}
