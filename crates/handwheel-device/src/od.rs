//! The handwheel's object dictionary: the engine's communication objects plus the
//! handwheel's own. These indices are the device's public interface.
//!
//! Each application object is one row of [`APP_OBJECTS`]: name, type, access, default,
//! write limits, PDO mapping and whether 0x1010 stores it. The run-time table ([`OD`]), the
//! stored record ([`STORED`], `app.rs`) and `eds/handwheel.eds` (`cargo xtask eds`) are
//! derived from the rows; what an object does lives in `app.rs`, one read and one write arm
//! per object with behaviour. The rows are constants: only the entries derived from them
//! reach the firmware image.

use canopen_slave::{
    standard_objects, Access, CommDefaults, DataType, Identity, Od, OdEntry, TpdoDefaults,
    STANDARD_OBJECTS,
};
use handwheel_core::{FeedRecord, DEFAULT_STEP_BACKLOG};

/// Feed enable: 1 = handwheel mode on. U8 rw, 0..1, default 0.
pub const FEED_ENABLE: u16 = 0x2000;
/// Feed format: 0 = feed record, 1 = the paper's unit-step stream. U8 rw, 0..1, default 0.
pub const FEED_FORMAT: u16 = 0x2001;
/// Feed session: the token a master opens its session with (1..7), carried in every feed
/// record; 0 = none. U8 rw, 0..7, default 0, never stored. The device ends it (back to 0) at
/// every boot and reset, at any other configuration write, and when the record sequence
/// outruns its pace (README "Feed record").
pub const FEED_SESSION: u16 = 0x2002;
/// Selection record: sub 1 axis, sub 2 multiplier, sub 3 epoch (all U8 ro, mappable).
pub const SELECTION: u16 = 0x2010;
/// Feed selection byte of the feed record: axis in bits 0-2, multiplier code in 3-4, the
/// epoch's low three bits in 5-7 (U8 ro, mappable).
pub const FEED_SELECTION: u16 = 0x2011;
/// Encoder record: sub 1 raw count (I32), sub 2 illegal transitions (U32), sub 3 counts per
/// detent (U8 rw 1/2/4), sub 4 invert (U8 rw 0/1).
pub const ENCODER: u16 = 0x2020;
/// Feed status: flags in bits 0-4, the session in 5-7 (U8 ro, mappable).
pub const FEED_STATUS: u16 = 0x2030;
/// Feed sequence: +1 per feed record (TPDO1) sent and per loss, +8 at a break (U16 ro,
/// mappable; README "Feed record").
pub const FEED_SEQUENCE: u16 = 0x2031;
/// The unit-step byte in flight in the paper's format (U8 ro, mappable; TPDO2).
pub const UNIT_STEP: u16 = 0x2032;
/// Feed diagnostics: sub 1 ignored detents (U32 ro), sub 2 dropped unit steps (U32 ro),
/// sub 3 unit-step backlog bound (U16 rw, 1..1000).
pub const FEED_DIAGNOSTICS: u16 = 0x2040;
/// Position value: the cumulative feed position (I32 ro, mappable). The index is the one CiA 406
/// gives an encoder's position, kept so that TPDO1's mapping (0x60040020) stays the same; the
/// device claims no profile (0x1000 = 0, see docs/CONFORMANCE.md).
pub const POSITION_VALUE: u16 = 0x6004;

/// Largest settable unit-step backlog: 1000 steps are 2 s of run-on at the default pacing,
/// the most any integrator could want from a compatibility mode.
pub const MAX_BACKLOG_BOUND: u16 = 1000;

/// Mapping entry `index << 16 | sub << 8 | bits`.
const fn map(index: u16, sub: u8, bits: u8) -> u32 {
    (index as u32) << 16 | (sub as u32) << 8 | bits as u32
}

/// TPDO1's default mapping: the 8-byte feed record, field by field as
/// `handwheel_core::FeedRecord::FIELDS` lays it out.
pub const FEED_RECORD_MAPPING: [u32; FeedRecord::FIELDS.len()] = {
    let mut mapping = [0; FeedRecord::FIELDS.len()];
    let mut i = 0;
    while i < mapping.len() {
        let f = &FeedRecord::FIELDS[i];
        mapping[i] = map(f.index, f.sub, ((f.bytes.end - f.bytes.start) * 8) as u8);
        i += 1;
    }
    mapping
};

/// TPDO2's default mapping: one unit-step byte.
pub const UNIT_STEP_MAPPING: [u32; 1] = [map(UNIT_STEP, 0, 8)];

/// What the device says it is.
pub const IDENTITY: Identity = Identity {
    // No device profile (CiA 301 generic device): the handwheel is not a CiA 406 encoder
    // (no preset, operating parameters, alarms, ...); see docs/CONFORMANCE.md.
    device_type: 0,
    vendor_id: 0,
    product_code: 1,
    revision: 1,
    device_name: "CNC handwheel",
    hardware_version: "STM32F103C8",
    software_version: env!("CARGO_PKG_VERSION"),
};

/// Communication defaults: heartbeat every second; TPDO1 the feed record, event-driven
/// with a 2 ms inhibit time (at most 500 frames/s, about 6 % of a 1 Mbit/s bus) and a 100 ms
/// event timer so a host that missed a frame is never more than 100 ms behind; TPDO2 the
/// unit-step stream, same pacing, and no event timer: repeating a unit step would be motion.
pub const COMM_DEFAULTS: CommDefaults = CommDefaults {
    heartbeat_ms: 1000,
    heartbeat_consumers: [0, 0],
    emcy_inhibit_100us: 0,
    tpdo: [
        TpdoDefaults {
            cob_id_base: 0x180,
            transmission_type: 254,
            inhibit_100us: 20,
            event_timer_ms: 100,
            mapping: &FEED_RECORD_MAPPING,
        },
        TpdoDefaults {
            cob_id_base: 0x280,
            transmission_type: 254,
            inhibit_100us: 20,
            event_timer_ms: 0,
            mapping: &UNIT_STEP_MAPPING,
        },
    ],
};

const STANDARD: [OdEntry; STANDARD_OBJECTS] = standard_objects(&IDENTITY, &COMM_DEFAULTS);

/// One sub-index of an application object, as the dictionary, the stored record and the
/// EDS see it. A record is a header row (its name, sub-index 0 = the highest sub-index)
/// followed by its sub-index rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AppObject {
    /// Object index.
    pub index: u16,
    /// Sub-index (0 for a variable and a record's header).
    pub sub: u8,
    /// The EDS's `ParameterName`: the record's own name on its header row.
    pub name: &'static str,
    /// Data type.
    pub data_type: DataType,
    /// Access rights.
    pub access: Access,
    /// The value after power-on (the highest sub-index on a header row).
    pub default: u32,
    /// The values an SDO write may set, `None` for the type's whole range.
    pub limits: Option<(i16, i16)>,
    /// PDO-mappable.
    pub mappable: bool,
    /// A parameter 0x1010 stores (in the application's section, in row order).
    pub stored: bool,
    /// A record's header row.
    pub header: bool,
}

impl AppObject {
    /// A variable, read-only, default 0, not mappable, not stored.
    const fn var(index: u16, sub: u8, name: &'static str, data_type: DataType) -> Self {
        Self {
            index,
            sub,
            name,
            data_type,
            access: Access::Ro,
            default: 0,
            limits: None,
            mappable: false,
            stored: false,
            header: false,
        }
    }

    /// The header row of a record with sub-indices 1..=`highest`.
    const fn record(index: u16, name: &'static str, highest: u8) -> Self {
        Self {
            access: Access::Const,
            default: highest as u32,
            header: true,
            ..Self::var(index, 0, name, DataType::U8)
        }
    }

    /// Writable within `min..=max`.
    const fn rw(mut self, min: i16, max: i16) -> Self {
        self.access = Access::Rw;
        self.limits = Some((min, max));
        self
    }

    const fn default(mut self, value: u32) -> Self {
        self.default = value;
        self
    }

    const fn mappable(mut self) -> Self {
        self.mappable = true;
        self
    }

    const fn stored(mut self) -> Self {
        self.stored = true;
        self
    }

    /// The run-time table's entry.
    const fn entry(&self) -> OdEntry {
        if self.header {
            return OdEntry::highest_sub(self.index, self.default as u8);
        }
        let mut e = OdEntry::app(self.index, self.sub, self.data_type, self.access);
        if let Some((min, max)) = self.limits {
            e = e.range(min as i64, max as i64);
        }
        if self.mappable {
            e = e.mappable();
        }
        e
    }
}

/// The handwheel's objects, sorted by (index, sub-index).
pub const APP_OBJECTS: &[AppObject] = {
    use DataType::{I32, U16, U32, U8};
    type O = AppObject;
    &[
        O::var(FEED_ENABLE, 0, "Feed enable", U8).rw(0, 1),
        O::var(FEED_FORMAT, 0, "Feed format", U8).rw(0, 1).stored(),
        O::var(FEED_SESSION, 0, "Feed session", U8).rw(0, 7),
        O::record(SELECTION, "Selection", 3),
        O::var(SELECTION, 1, "Axis", U8).mappable(),
        O::var(SELECTION, 2, "Multiplier", U8).default(1).mappable(),
        O::var(SELECTION, 3, "Selection epoch", U8).mappable(),
        O::var(FEED_SELECTION, 0, "Feed selection", U8).mappable(),
        O::record(ENCODER, "Encoder", 4),
        O::var(ENCODER, 1, "Raw count", I32).mappable(),
        O::var(ENCODER, 2, "Illegal transitions", U32).mappable(),
        O::var(ENCODER, 3, "Counts per detent", U8)
            .rw(1, 4)
            .default(4)
            .stored(),
        O::var(ENCODER, 4, "Invert direction", U8).rw(0, 1).stored(),
        O::var(FEED_STATUS, 0, "Feed status", U8).mappable(),
        O::var(FEED_SEQUENCE, 0, "Feed sequence", U16).mappable(),
        O::var(UNIT_STEP, 0, "Unit step", U8).mappable(),
        O::record(FEED_DIAGNOSTICS, "Feed diagnostics", 3),
        O::var(FEED_DIAGNOSTICS, 1, "Ignored detents", U32),
        O::var(FEED_DIAGNOSTICS, 2, "Dropped unit steps", U32),
        O::var(FEED_DIAGNOSTICS, 3, "Unit-step backlog bound", U16)
            .rw(1, MAX_BACKLOG_BOUND as i16)
            .default(DEFAULT_STEP_BACKLOG as u32)
            .stored(),
        O::var(POSITION_VALUE, 0, "Position value", I32).mappable(),
    ]
};

/// Notes the EDS carries before an object's section: what a master must know beyond the
/// object's type and limits.
pub const EDS_NOTES: [(u16, &str); 6] = [
    (
        0x1010,
        "0x1010 \"save\" and 0x1011 \"load\" write the parameter page (README \"Storing parameters\"):
- storing what is stored already writes nothing and succeeds;
- a changed store appends a record; a full page (six records) is erased first, at most
  8 erases at once, then one per 24 h of powered time: beyond that the store writes
  nothing and aborts 0x08000020 (a wrong signature also aborts 0x08000020, checked first);
- while the feed is enabled (0x2000 = 1) every save and load aborts 0x08000022: writing
  flash would stall the CPU and lose wheel edges.
LSS \"store configuration\" follows the same rules: error 255 with byte 2 = 1 (wear budget)
or 2 (feed enabled).",
    ),
    (
        0x1011,
        "0x1011: the defaults apply from the next reset; \"nothing stored\" is a record like any
other (see 0x1010 above for when it is refused).",
    ),
    (
        FEED_SESSION,
        "A master opens its session by writing 1..7 last in its configuration; every feed record
carries it (0x2030 bits 5-7). A change of it is a new selection epoch with the feed off. The
device ends it (0) at power-on, reset node and reset communication, at any successful SDO
write other than to 0x2000, 0x2002, 0x1003, 0x1010 and 0x1011, and when the feed sequence
outruns its pace (64 numbers at once, then one per ms): README \"Feed record\".",
    ),
    (
        FEED_SELECTION,
        "Bits 0-2: axis (0 none, 1..5 = X, Y, Z, W, V); bits 3-4: multiplier code (0 = x1,
1 = x10, 2 = x100); bits 5-7: the low three bits of the selection epoch (0x2010:3) of the
state the value describes (in TPDO1: the record's own).",
    ),
    (
        FEED_STATUS,
        "Bits 0-4: status flags; bits 5-7: the session (0x2002) of the state the value describes
(in TPDO1: the record's own).",
    ),
    (
        FEED_SEQUENCE,
        "+1 per feed record sent, and per loss (a held record dropped, an epoch that ended unseen);
+8 at a break (start, stop, reset, a blocked transmit path); wraps at 65536: README
\"Feed record\".",
    ),
];

/// The run-time entries of [`APP_OBJECTS`]; a record whose header does not name its last
/// sub-index fails the build.
const HANDWHEEL: [OdEntry; APP_OBJECTS.len()] = {
    let mut entries = [OdEntry::highest_sub(0, 0); APP_OBJECTS.len()];
    let mut i = 0;
    while i < entries.len() {
        let o = &APP_OBJECTS[i];
        entries[i] = o.entry();
        if o.header {
            let mut last = i;
            while last + 1 < APP_OBJECTS.len() && APP_OBJECTS[last + 1].index == o.index {
                last += 1;
            }
            assert!(
                last > i && APP_OBJECTS[last].sub as u32 == o.default,
                "a record's header names its highest sub-index"
            );
        }
        i += 1;
    }
    entries
};

/// How many parameters 0x1010 stores in the application's section.
pub const STORED_LEN: usize = {
    let mut n = 0;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        n += APP_OBJECTS[i].stored as usize;
        i += 1;
    }
    n
};

/// The stored parameters in the order of the application's section: (index, sub-index,
/// size in bytes), from the rows marked stored.
pub const STORED: [(u16, u8, u8); STORED_LEN] = {
    let mut list = [(0, 0, 0); STORED_LEN];
    let mut k = 0;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        let o = &APP_OBJECTS[i];
        if o.stored {
            let size = match o.data_type.size() {
                Some(n) => n as u8,
                None => panic!("a stored parameter is a number"),
            };
            list[k] = (o.index, o.sub, size);
            k += 1;
        }
        i += 1;
    }
    list
};

/// The whole dictionary; an unsorted or inconsistent table fails the build.
pub static OD: Od = Od::checked(&[&STANDARD, &HANDWHEEL]);
