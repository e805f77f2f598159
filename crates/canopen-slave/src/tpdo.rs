//! Transmit PDOs: communication (0x1800+n) and mapping (0x1A00+n) parameters and the
//! transmission-type timing rules of CiA 301 7.2.2.

use crate::abort::SdoAbort;
use crate::cob_id::COB_INVALID;
use crate::frame::MAX_STANDARD_ID;
use crate::mapping::{split_mapping, PdoMapping};
use crate::nmt::NmtState;
use crate::od::{Od, OdEntry};
use crate::time::Instant;

pub use crate::mapping::MAX_MAPPED;

/// Number of transmit PDOs.
pub const TPDOS: usize = 2;
/// COB-ID bit 30: no RTR allowed on this PDO.
pub const NO_RTR: u32 = 1 << 30;
/// Checks that `entry` names an object that can go into a TPDO; returns it with its size in
/// bytes. Only whole objects are mapped: the length must equal the object's size.
pub(crate) fn check_mapping(od: &Od, entry: u32) -> Result<(&'static OdEntry, usize), SdoAbort> {
    let (index, sub, bits) = split_mapping(entry);
    let e = od.find(index, sub)?;
    let size = e.data_type().size().ok_or(SdoAbort::NotMappable)?;
    if !e.is_mappable() || !e.access().readable() || usize::from(bits) != size * 8 {
        return Err(SdoAbort::NotMappable);
    }
    Ok((e, size))
}

/// [`check_mapping`] as the mapping's write check.
fn check_entry(od: &Od, entry: u32) -> Result<usize, SdoAbort> {
    check_mapping(od, entry).map(|(_, size)| size)
}

/// One transmit PDO: its parameters and its transmission state.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) struct Tpdo {
    cob_id: u32,
    transmission_type: u8,
    inhibit_100us: u16,
    event_timer_ms: u16,
    mapping: PdoMapping,
    /// An event (application request, event timer, entry to Operational) awaits sending.
    pending: bool,
    /// No frame of this PDO before this instant (inhibit time, or a retry after a full sink).
    hold_until: Instant,
    event_at: Option<Instant>,
    sync_count: u8,
}

impl Tpdo {
    pub(crate) const fn new() -> Self {
        Self {
            cob_id: COB_INVALID,
            transmission_type: 255,
            inhibit_100us: 0,
            event_timer_ms: 0,
            mapping: PdoMapping::new(),
            pending: false,
            hold_until: Instant::ZERO,
            event_at: None,
            sync_count: 0,
        }
    }

    fn valid(&self) -> bool {
        self.cob_id & COB_INVALID == 0
    }

    /// Whether the PDO exists and has something mapped.
    pub(crate) fn active(&self) -> bool {
        self.valid() && self.mapping.any()
    }

    /// Types 254/255: sent on events and on the event timer, subject to the inhibit time.
    pub(crate) fn event_driven(&self) -> bool {
        self.transmission_type >= 254
    }

    /// The raw 0x1800+n:01 entry.
    pub(crate) const fn cob_id(&self) -> u32 {
        self.cob_id
    }

    /// CAN-ID to send on.
    pub(crate) fn can_id(&self) -> u16 {
        (self.cob_id & u32::from(MAX_STANDARD_ID)) as u16
    }

    /// The active mapping entries.
    pub(crate) fn mapping(&self) -> &[u32] {
        self.mapping.entries()
    }

    /// Reads 0x1800+n.
    pub(crate) fn read_comm(&self, sub: u8) -> Result<u32, SdoAbort> {
        match sub {
            // Bit 30 reads 1 ("no RTR allowed"): remote frames are not served (CiA 301).
            1 => Ok(self.cob_id | NO_RTR),
            2 => Ok(self.transmission_type.into()),
            3 => Ok(self.inhibit_100us.into()),
            5 => Ok(self.event_timer_ms.into()),
            _ => Err(SdoAbort::NoSubIndex),
        }
    }

    /// Checked write of 0x1800+n. The COB-ID (sub 1) is the engine's to check first
    /// (`check_cob_id_write`, and uniqueness within the node, which needs every object).
    /// Its one caller is 0x1800's row, where inlining it keeps the image smaller.
    #[inline]
    pub(crate) fn write_comm(
        &mut self,
        sub: u8,
        v: u32,
        now: Instant,
        operational: bool,
    ) -> Result<(), SdoAbort> {
        match sub {
            1 => {}
            // 241..=251 are reserved; 252/253 (RTR only) are not supported.
            2 if matches!(v, 241..=253) => return Err(SdoAbort::InvalidValue),
            // CiA 301: the inhibit time may not change while the PDO exists.
            3 if self.valid() => return Err(SdoAbort::InvalidValue),
            2 | 3 | 5 => {}
            _ => return Err(SdoAbort::NoSubIndex),
        }
        self.set_comm(sub, v);
        self.sync_count = 0;
        // A new COB-ID, type or timer takes effect now: restart the event timer.
        self.event_at = None;
        if operational {
            self.arm_event_timer(now);
        }
        Ok(())
    }

    /// Unchecked write of 0x1800+n (defaults, stored parameters).
    pub(crate) fn set_comm(&mut self, sub: u8, v: u32) {
        // Truncations are intended: the table types these sub-indices as U8/U16.
        match sub {
            1 => self.cob_id = v,
            2 => self.transmission_type = v as u8,
            3 => self.inhibit_100us = v as u16,
            5 => self.event_timer_ms = v as u16,
            _ => {}
        }
    }

    /// Reads 0x1A00+n.
    pub(crate) fn read_mapping(&self, sub: u8) -> Result<u32, SdoAbort> {
        self.mapping.read(sub)
    }

    /// Checked write of 0x1A00+n ([`PdoMapping::write`]: objects a TPDO may carry).
    pub(crate) fn write_mapping(&mut self, sub: u8, v: u32, od: &Od) -> Result<(), SdoAbort> {
        let valid = self.valid();
        self.mapping.write(sub, v, valid, od, check_entry)
    }

    /// Unchecked write of 0x1A00+n (defaults, stored parameters).
    pub(crate) fn set_mapping(&mut self, sub: u8, v: u32) {
        self.mapping.set(sub, v);
    }

    fn arm_event_timer(&mut self, now: Instant) {
        self.event_at = (self.active() && self.event_driven() && self.event_timer_ms != 0)
            .then(|| now.after_ms(self.event_timer_ms));
    }

    /// Entry to Operational: timers start; an `announce`d event-driven PDO is sent at once.
    fn start(&mut self, now: Instant, announce: bool) {
        self.pending = announce && self.active() && self.event_driven();
        self.hold_until = Instant::ZERO;
        self.sync_count = 0;
        self.arm_event_timer(now);
    }

    /// Leaving Operational: nothing may be sent any more.
    fn stop(&mut self) {
        self.pending = false;
        self.event_at = None;
        self.sync_count = 0;
    }

    /// The application changed mapped data (types 0, 254, 255; cyclic types ignore it).
    pub(crate) fn request(&mut self) {
        if self.active() && (self.transmission_type == 0 || self.event_driven()) {
            self.pending = true;
        }
    }

    /// Whether an event-driven frame should go out now (event timer folded into `pending`).
    pub(crate) fn event_due(&mut self, now: Instant) -> bool {
        if !self.active() || !self.event_driven() {
            return false;
        }
        if self.event_at.is_some_and(|t| now >= t) {
            self.event_at = None;
            self.pending = true;
        }
        self.pending && now >= self.hold_until
    }

    /// A SYNC arrived: whether this PDO sends now.
    pub(crate) fn on_sync(&mut self) -> bool {
        if !self.active() {
            return false;
        }
        match self.transmission_type {
            0 => self.pending,
            n @ 1..=240 => {
                self.sync_count = self.sync_count.saturating_add(1);
                if self.sync_count >= n {
                    self.sync_count = 0;
                    true
                } else {
                    false
                }
            }
            _ => false,
        }
    }

    /// The frame went out: start the inhibit time and restart the event timer.
    pub(crate) fn sent(&mut self, now: Instant) {
        self.pending = false;
        self.hold_until = now.add_100us(self.inhibit_100us);
        self.arm_event_timer(now);
    }

    /// The application withdrew the event: nothing is sent and the inhibit time does not
    /// start, but the event timer starts over as if a frame had gone out.
    pub(crate) fn withdrawn(&mut self, now: Instant) {
        self.pending = false;
        self.arm_event_timer(now);
    }

    /// The sink was full: try again a little later instead of spinning.
    pub(crate) fn retry_later(&mut self, now: Instant) {
        self.hold_until = now.after_ms(1);
    }

    /// When `poll` must next look at this PDO (in Operational).
    pub(crate) fn deadline(&self) -> Option<Instant> {
        if !self.active() || !self.event_driven() {
            None
        } else if self.pending {
            Some(self.hold_until)
        } else {
            self.event_at
        }
    }
}

/// NMT state change: the PDOs start on entry to Operational and stop on leaving it. Only
/// TPDO1 announces itself (CiA 406 does so for the position): a PDO carrying events rather
/// than state must not be repeated by a state change.
pub(crate) fn on_nmt_state(tpdos: &mut [Tpdo; TPDOS], next: NmtState, now: Instant) {
    for (n, t) in tpdos.iter_mut().enumerate() {
        if next == NmtState::Operational {
            t.start(now, n == 0);
        } else {
            t.stop();
        }
    }
}
