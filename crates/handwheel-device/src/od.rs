//! The handwheel's object dictionary: the engine's communication objects plus the
//! handwheel's own. These indices are the device's public interface.
//!
//! Each application object is one row of [`APP_OBJECTS`]: name, type, access, default,
//! write limits, PDO mapping, and how it is read and written ([`Behaviour`]): a parameter
//! 0x1010 stores, a value of the wheel with the functions that read and write it, the
//! unit-step byte in flight. The run-time table ([`OD`]), the stored record ([`STORED`]),
//! the read and write paths' lookups (`WHEEL_READS`, `WHEEL_WRITES`; `app.rs` carries
//! them out) and `eds/handwheel.eds` (`cargo xtask eds`) are derived from the rows. The rows
//! are constants: only what is derived from them reaches the firmware image, not the names.
//! A new stored parameter is a row, and a line in `WheelParameters::apply` if it drives the
//! wheel (a new stored layout needs a new `BLOB_VERSION`).

use canopen_loader::header::PRODUCT;
use canopen_slave::{
    standard_objects, Access, CommDefaults, DataType, Identity, Od, OdEntry, SdoAbort,
    TpdoDefaults, STANDARD_OBJECTS,
};
use handwheel_core::{Axis, FeedRecord, FeedState, FeedStatus, Handwheel, DEFAULT_STEP_BACKLOG};

/// Program control (CiA 302-3), sub 1: U8 rw. Reads 1 ("started": this is the application);
/// writing 0 ("stop") resets into the resident loader, only in Pre-operational with the feed
/// disabled; 1 ("start") is already done; 0x80 ("confirm") ends the trial boot of a new image;
/// 3 ("clear") is the loader's (stop first); 2 and other values are refused.
/// docs/FIRMWARE-UPDATE.md.
pub const PROGRAM_CONTROL: u16 = 0x1F51;
/// Program software identification (CiA 302-3), sub 1: U32 ro, the `crc` of the application's
/// own image header (the CRC-32 of the image that runs).
pub const PROGRAM_SOFTWARE_ID: u16 = 0x1F56;
/// Flash status identification (CiA 302-3), sub 1: U32 ro, 0 in the application (no download
/// in progress, no error): downloads are the loader's.
pub const FLASH_STATUS: u16 = 0x1F57;
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
/// Sequence probe: U32 rw. A write sets the nonce (its low 13 bits); a read gives the
/// sequence number the next feed record carries in bits 16-31, the session in bits 13-15 and
/// the nonce in bits 0-12. A write of it keeps the session: a master dates the records it
/// receives with it while its session runs (README "The contract").
pub const SEQUENCE_PROBE: u16 = 0x2033;
/// Session key: written by the master that opened the session, carried by its probes.
pub const SESSION_KEY: u16 = 0x2034;
/// Device uptime: U32 ro, milliseconds since the device started (power-on or any reset of
/// its MCU; NMT's reset node and reset communication keep it counting), wrapping after
/// 49.7 days. A master that read it before can tell that no power cycle came since: a new
/// life's uptime is never more than the time since.
pub const DEVICE_UPTIME: u16 = 0x2035;
/// Jog live: U8 ro, mappable, 1 exactly when a detent turned now moves the feed position
/// (the feed enabled and an axis selected: `FeedAccumulator::takes_motion`, the rule the
/// accumulator itself follows), else 0. The device drives its "jog live" LED (board output 1)
/// from it; the CNC's outputs (0x6A00) never reach that LED.
pub const JOG_LIVE: u16 = 0x2036;

/// A session opens (0x2002 = 1..7) only this long after the device started: a record of a
/// new power life never carries a session within this of the life's start, longer than the
/// time a host's probe dates records for (`DATE_LIMIT`, 0.35 s, in the host's core), so
/// that no probe answered before a power cycle dates a record made after it.
pub const SESSION_DELAY_MS: u64 = 500;
/// Feed diagnostics: sub 1 ignored detents (U32 ro), sub 2 dropped unit steps (U32 ro),
/// sub 3 unit-step backlog bound (U16 rw, 1..1000).
pub const FEED_DIAGNOSTICS: u16 = 0x2040;
/// Position value: the cumulative feed position (I32 ro, mappable). The index is the one CiA 406
/// gives an encoder's position, kept so that TPDO1's mapping (0x60040020) stays the same; the
/// device claims no profile (0x1000 = 0, see docs/CONFORMANCE.md).
pub const POSITION_VALUE: u16 = 0x6004;
/// Write output 8-bit, sub 1: U8 rw, PDO-mappable, 0 after power-on and reset node; bit n is
/// digital output n + 1 (board outputs 2..8 carry bits 0..6, bit 7 has no pin). CiA 401's
/// "write output 8-bit" (0x6200) at the second logical device's place (CiA 301: +0x800), not
/// at 0x6200 itself, which CiA 406 (whose position value 0x6004 is kept) gives its cyclic
/// timer; no profile is claimed (0x1000 = 0, docs/CONFORMANCE.md). It reads the outputs as
/// driven: after an error reaction (0x6A06, 0x6A07) the value the
/// reaction left, until a master writes it again.
pub const WRITE_OUTPUTS: u16 = 0x6A00;
/// Error mode output 8-bit, sub 1: U8 rw, stored by 0x1010, default 0xFF. Bit n set: on an
/// error (master heartbeat lost, NMT Stopped, an RPDO deadline missed) output n + 1 takes
/// its bit of 0x6A07; clear: it keeps its value. CiA 401's 0x6206 at +0x800.
pub const OUTPUT_ERROR_MODE: u16 = 0x6A06;
/// Error value output 8-bit, sub 1: U8 rw, stored by 0x1010, default 0: the value each
/// output whose 0x6A06 bit is set takes on an error. CiA 401's 0x6207 at +0x800.
pub const OUTPUT_ERROR_VALUE: u16 = 0x6A07;

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
    vendor_id: PRODUCT.vendor_id,
    product_code: PRODUCT.product_code,
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
    // RPDO1 on 0x200 + node-ID drives the CiA 401 digital outputs (0x6A00:1), acting at once.
    rpdo: [canopen_slave::RpdoDefaults {
        mapping: &[0x6A00_0108],
        ..canopen_slave::RpdoDefaults::predefined(1)
    }],
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

/// Reads an object of the wheel under its lock, from the feed state it describes (the
/// record's own while TPDO1 is built, else the present one) or from the wheel: its value as a
/// raw number (two's complement for signed types).
pub type ReadFn = fn(&FeedState, &Handwheel) -> u32;
/// Writes a value the table's limits have checked into the wheel, under its lock; what the
/// wheel's state refuses is an abort, with nothing changed.
pub type WriteFn = fn(&mut Handwheel, u32) -> Result<(), SdoAbort>;

/// How an application object is read and written: the part of a row that `app.rs` carries
/// out, as CANopenNode attaches read and write functions to an object (`OD_extension_t`) and
/// zencan's table entries answer their own reads and writes.
#[derive(Clone, Copy, Debug, Hash)]
pub enum Behaviour {
    /// A record's header: its highest sub-index, a constant the table answers.
    Header,
    /// A parameter 0x1010 stores (in the application's section, in row order): read from and
    /// written to the device's [`WheelParameters`](crate::WheelParameters), which pushes a
    /// written value into the wheel.
    Stored,
    /// The unit-step byte in flight, which the device keeps for TPDO2.
    UnitStep,
    /// One of CiA 302-3's program download objects, which the application answers for the
    /// loader ([`Program`]).
    Program(Program),
    /// The device's uptime, which the device keeps from its start.
    Uptime,
    /// 0x6A00:1, the digital outputs as driven, which the device keeps: a write sets them,
    /// an error reaction changes them.
    Outputs,
    /// Read from the wheel under its lock and, if writable, written there.
    Wheel {
        /// The value.
        read: ReadFn,
        /// The write; `None` for a read-only object.
        write: Option<WriteFn>,
        /// Writing 1 turns the feed on: refused (0x08000022) unless the device allows it now.
        enables_feed: bool,
        /// Writing other than 0 opens a session: refused (0x08000022) while the device is
        /// younger than [`SESSION_DELAY_MS`].
        opens_session: bool,
    },
}

/// CiA 302-3's program download objects as the application has them: the download itself
/// (0x1F50) is the resident loader's, the application's part is to reset into it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Program {
    /// 0x1F51:1 program control.
    Control,
    /// 0x1F56:1 program software identification: the image's CRC-32.
    SoftwareId,
    /// 0x1F57:1 flash status identification: always 0 here.
    FlashStatus,
}

/// One sub-index of an application object, as the dictionary, the stored record, the EDS
/// and the device's read and write paths see it. A record is a header row (its name,
/// sub-index 0 = the highest sub-index) followed by its sub-index rows.
#[derive(Clone, Copy, Debug, Hash)]
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
    /// Values within the limits that a write refuses all the same (0x06090030): bit `n` for
    /// value `n`.
    pub refused: u16,
    /// PDO-mappable.
    pub mappable: bool,
    /// How it is read and written.
    pub behaviour: Behaviour,
    /// On a header row: the object is an ARRAY (sub-indices of one type, as CiA 302-3 has
    /// its objects), not a RECORD.
    pub array: bool,
}

impl AppObject {
    /// A variable, read-only, default 0, not mappable.
    const fn new(
        index: u16,
        sub: u8,
        name: &'static str,
        data_type: DataType,
        behaviour: Behaviour,
    ) -> Self {
        Self {
            index,
            sub,
            name,
            data_type,
            access: Access::Ro,
            default: 0,
            limits: None,
            refused: 0,
            mappable: false,
            behaviour,
            array: false,
        }
    }

    /// A parameter 0x1010 stores.
    const fn stored(index: u16, sub: u8, name: &'static str, data_type: DataType) -> Self {
        Self::new(index, sub, name, data_type, Behaviour::Stored)
    }

    /// A value of the wheel, `read` under its lock.
    const fn wheel(
        index: u16,
        sub: u8,
        name: &'static str,
        data_type: DataType,
        read: ReadFn,
    ) -> Self {
        let behaviour = Behaviour::Wheel {
            read,
            write: None,
            enables_feed: false,
            opens_session: false,
        };
        Self::new(index, sub, name, data_type, behaviour)
    }

    /// The header row of a record with sub-indices 1..=`highest`.
    const fn record(index: u16, name: &'static str, highest: u8) -> Self {
        Self {
            access: Access::Const,
            default: highest as u32,
            ..Self::new(index, 0, name, DataType::U8, Behaviour::Header)
        }
    }

    /// The header row of an array with sub-indices 1..=`highest`.
    const fn array(index: u16, name: &'static str, highest: u8) -> Self {
        Self {
            array: true,
            ..Self::record(index, name, highest)
        }
    }

    /// A program download object.
    const fn program(index: u16, name: &'static str, data_type: DataType, p: Program) -> Self {
        Self::new(index, 1, name, data_type, Behaviour::Program(p))
    }

    /// Writable, every value of its type passed to the write (which refuses what it must).
    const fn writable(mut self) -> Self {
        self.access = Access::Rw;
        self
    }

    /// Writable within `min..=max`.
    const fn rw(mut self, min: i16, max: i16) -> Self {
        self.access = Access::Rw;
        self.limits = Some((min, max));
        self
    }

    /// A write of `value` (below 16, within the limits) is refused all the same.
    const fn refusing(mut self, value: u8) -> Self {
        self.refused |= 1 << value;
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

    /// A value of the wheel that `write` sets.
    const fn writes(mut self, write: WriteFn) -> Self {
        match &mut self.behaviour {
            Behaviour::Wheel { write: w, .. } => *w = Some(write),
            _ => panic!("only the wheel's values are written through a function"),
        }
        self
    }

    /// Writing 1 turns the feed on ([`Behaviour::Wheel`]'s `enables_feed`).
    const fn enables_feed(mut self) -> Self {
        match &mut self.behaviour {
            Behaviour::Wheel { enables_feed, .. } => *enables_feed = true,
            _ => panic!("only a value of the wheel enables the feed"),
        }
        self
    }

    /// Writing other than 0 opens a session ([`Behaviour::Wheel`]'s `opens_session`).
    const fn opens_session(mut self) -> Self {
        match &mut self.behaviour {
            Behaviour::Wheel { opens_session, .. } => *opens_session = true,
            _ => panic!("only a value of the wheel opens a session"),
        }
        self
    }

    /// Write-only: every value of its type passed to the write; a read is refused
    /// (0x06010001).
    const fn write_only(mut self) -> Self {
        self.access = Access::Wo;
        self
    }

    /// A record's header row.
    pub const fn is_header(&self) -> bool {
        matches!(self.behaviour, Behaviour::Header)
    }

    /// A parameter 0x1010 stores.
    pub const fn is_stored(&self) -> bool {
        matches!(self.behaviour, Behaviour::Stored)
    }

    /// The run-time table's entry.
    const fn entry(&self) -> OdEntry {
        if self.is_header() {
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
        O::array(PROGRAM_CONTROL, "Program control", 1),
        // Reads 1: the application is the program that runs ("started").
        O::program(PROGRAM_CONTROL, "Program control 1", U8, Program::Control)
            .writable()
            .default(1),
        O::array(PROGRAM_SOFTWARE_ID, "Program software identification", 1),
        O::program(
            PROGRAM_SOFTWARE_ID,
            "Program software identification 1",
            U32,
            Program::SoftwareId,
        ),
        O::array(FLASH_STATUS, "Flash status identification", 1),
        O::program(
            FLASH_STATUS,
            "Flash status identification 1",
            U32,
            Program::FlashStatus,
        ),
        O::wheel(FEED_ENABLE, 0, "Feed enable", U8, |state, _| {
            state.status.contains(FeedStatus::ENABLED).into()
        })
        .rw(0, 1)
        .writes(|w, value| {
            w.feed.set_enabled(value == 1);
            Ok(())
        })
        .enables_feed(),
        O::stored(FEED_FORMAT, 0, "Feed format", U8).rw(0, 1),
        O::wheel(FEED_SESSION, 0, "Feed session", U8, |_, wheel| {
            wheel.feed.session().into()
        })
        .rw(0, 7)
        .writes(|w, value| {
            w.feed.set_session(value as u8);
            Ok(())
        })
        .opens_session(),
        O::record(SELECTION, "Selection", 3),
        O::wheel(SELECTION, 1, "Axis", U8, |state, _| {
            Axis::option_value(state.axis).into()
        })
        .mappable(),
        O::wheel(SELECTION, 2, "Multiplier", U8, |state, _| {
            state.multiplier.factor().into()
        })
        .default(1)
        .mappable(),
        O::wheel(SELECTION, 3, "Selection epoch", U8, |state, _| {
            state.epoch.into()
        })
        .mappable(),
        O::wheel(FEED_SELECTION, 0, "Feed selection", U8, |state, _| {
            state.selection_byte().into()
        })
        .mappable(),
        O::record(ENCODER, "Encoder", 4),
        // Two's complement bytes of the signed objects, as CiA 301 sends them.
        O::wheel(ENCODER, 1, "Raw count", I32, |_, wheel| {
            wheel.count() as u32
        })
        .mappable(),
        O::wheel(ENCODER, 2, "Illegal transitions", U32, |_, wheel| {
            wheel.illegal_transitions()
        })
        .mappable(),
        O::stored(ENCODER, 3, "Counts per detent", U8)
            .rw(1, 4)
            .refusing(3)
            .default(4),
        O::stored(ENCODER, 4, "Invert direction", U8).rw(0, 1),
        O::wheel(FEED_STATUS, 0, "Feed status", U8, |state, _| {
            state.status_byte().into()
        })
        .mappable(),
        O::wheel(FEED_SEQUENCE, 0, "Feed sequence", U16, |_, wheel| {
            wheel.feed.record_sequence().into()
        })
        .mappable(),
        O::new(UNIT_STEP, 0, "Unit step", U8, Behaviour::UnitStep).mappable(),
        O::wheel(SEQUENCE_PROBE, 0, "Sequence probe", U32, |_, wheel| {
            wheel.feed.sequence_probe()
        })
        .writable()
        .writes(|w, value| w.feed.write_probe(value).map_err(|_| SdoAbort::DeviceState)),
        O::wheel(SESSION_KEY, 0, "Session key", U16, |_, _| 0)
            .write_only()
            .writes(|w, value| {
                w.feed
                    .set_session_key(value as u16)
                    .map_err(|_| SdoAbort::DeviceState)
            }),
        O::new(DEVICE_UPTIME, 0, "Device uptime", U32, Behaviour::Uptime),
        O::wheel(JOG_LIVE, 0, "Jog live", U8, |_, wheel| {
            wheel.feed.takes_motion().into()
        })
        .mappable(),
        O::record(FEED_DIAGNOSTICS, "Feed diagnostics", 3),
        O::wheel(FEED_DIAGNOSTICS, 1, "Ignored detents", U32, |_, wheel| {
            wheel.feed.ignored_detents()
        }),
        O::wheel(
            FEED_DIAGNOSTICS,
            2,
            "Dropped unit steps",
            U32,
            |_, wheel| wheel.feed.dropped_steps(),
        ),
        O::stored(FEED_DIAGNOSTICS, 3, "Unit-step backlog bound", U16)
            .rw(1, MAX_BACKLOG_BOUND as i16)
            .default(DEFAULT_STEP_BACKLOG as u32),
        O::wheel(POSITION_VALUE, 0, "Position value", I32, |state, _| {
            state.position as u32
        })
        .mappable(),
        O::array(WRITE_OUTPUTS, "Write output 8-bit", 1),
        O::new(
            WRITE_OUTPUTS,
            1,
            "Write outputs 1 to 8",
            U8,
            Behaviour::Outputs,
        )
        .writable()
        .mappable(),
        O::array(OUTPUT_ERROR_MODE, "Error mode output 8-bit", 1),
        O::stored(OUTPUT_ERROR_MODE, 1, "Error mode outputs 1 to 8", U8)
            .writable()
            .default(0xFF),
        O::array(OUTPUT_ERROR_VALUE, "Error value output 8-bit", 1),
        O::stored(OUTPUT_ERROR_VALUE, 1, "Error value outputs 1 to 8", U8).writable(),
    ]
};

/// Notes the EDS carries before an object's section: what a master must know beyond the
/// object's type and limits.
pub const EDS_NOTES: [(u16, &str); 11] = [
    (
        PROGRAM_CONTROL,
        "0x1F51:1 program control (CiA 302-3): 0 (stop) resets into the resident loader, which
takes a firmware update (0x1F50 there; its 0x1000 reads 0x544F4F42): accepted only in
Pre-operational with the feed disabled, the answer goes out first. 1 (start): nothing to do;
0x80 (confirm, as Zephyr's master writes it): ends the trial boot of a new image; 3 (clear,
the loader's): 0x08000022; other values 0x06090030; any write outside Pre-operational
0x08000022. 0x1F56:1 is the running image's CRC-32.",
    ),
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
write other than to 0x2000, 0x2002, 0x2033, 0x2034, 0x1003, 0x1010, 0x1011 and the outputs'
0x6A00, 0x6A06, 0x6A07, and when the feed sequence outruns its pace (64 numbers at once, then
one per ms): README \"Feed record\".
A session opens only 0.5 s after the device started (earlier: abort 0x08000022).",
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
    (
        SEQUENCE_PROBE,
        "A write sets the nonce (the value's low 13 bits; it keeps the session); its bits 16-31,
if not 0, must be the session key (0x2034), else the write is refused (0x08000022). A read
gives the sequence number the next feed record carries (0x2031) in bits 16-31, the session
(0x2002) in bits 13-15 and the nonce last written in bits 0-12. A master that writes a nonce
of its own with its key and reads it back with its session and the number n knows that every
record numbered n or later was made after it sent the write, in the session it opened:
README \"The contract\".",
    ),
    (
        JOG_LIVE,
        "1 exactly when a detent turned now moves the feed position (0x6004): the feed enabled
(0x2000 = 1, which also means Operational, the master's heartbeat present and the transmit
path draining) and an axis selected, in either feed format. Board output 1, the \"jog live\"
LED, shows it; 0x6A00 never drives that output.",
    ),
    (
        SESSION_KEY,
        "Written by the master that opened the session, right after 0x2002 (refused with
0x08000022 while no session is open); 0 again whenever the session changes or ends. The
master's probes (0x2033) carry it, so a session someone else opened with the same token is
never taken for its own. Write-only, so that no tool saves it.",
    ),
    (
        WRITE_OUTPUTS,
        "0x6A00, 0x6A06, 0x6A07 are CiA 401's 0x6200, 0x6206, 0x6207 at the second logical
device's place (+0x800), clear of CiA 406's 0x6200 (cyclic timer); the device claims no
profile (0x1000 = 0). 0x6A00:1 bit n drives board output n + 2 (bits 0..6; bit 7 has no pin)
and reads the outputs as driven. On an error (the master's heartbeat lost, NMT Stopped, an
RPDO deadline missed) every output whose 0x6A06:1 bit is set takes its 0x6A07:1 bit, in the
round that learns of it, and keeps it until a master writes 0x6A00:1 again; a recovery
changes nothing. Reset communication keeps the outputs; reset node and power-on set them to
0. 0x6A06:1 (default 0xFF) and 0x6A07:1 (default 0) are stored by 0x1010. Writes of these
objects keep the feed session.",
    ),
];

/// The run-time entries of [`APP_OBJECTS`]; a record whose header does not name its last
/// sub-index, a row writable without a write and a refused value nothing checks fail the
/// build.
const HANDWHEEL: [OdEntry; APP_OBJECTS.len()] = {
    let mut entries = [OdEntry::highest_sub(0, 0); APP_OBJECTS.len()];
    let mut i = 0;
    while i < entries.len() {
        let o = &APP_OBJECTS[i];
        entries[i] = o.entry();
        if o.is_header() {
            let mut last = i;
            while last + 1 < APP_OBJECTS.len() && APP_OBJECTS[last + 1].index == o.index {
                last += 1;
            }
            assert!(
                last > i && APP_OBJECTS[last].sub as u32 == o.default,
                "a record's header names its highest sub-index"
            );
        }
        let written = match o.behaviour {
            Behaviour::Stored | Behaviour::Program(Program::Control) | Behaviour::Outputs => true,
            Behaviour::Wheel { write, .. } => write.is_some(),
            Behaviour::Header | Behaviour::UnitStep | Behaviour::Program(_) | Behaviour::Uptime => {
                false
            }
        };
        assert!(
            written == o.access.writable(),
            "a row is writable exactly when something writes it"
        );
        assert!(
            o.refused == 0 || o.is_stored(),
            "only a stored parameter refuses values (WheelParameters::set checks them)"
        );
        i += 1;
    }
    entries
};

/// The rows the run-time lookups hold.
#[derive(Clone, Copy)]
enum Rows {
    /// Stored parameters.
    Stored,
    /// Values of the wheel.
    Read,
    /// Values of the wheel with a write.
    Written,
}

/// How many rows are of `kind`.
const fn count(kind: Rows) -> usize {
    let mut n = 0;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        n += match (APP_OBJECTS[i].behaviour, kind) {
            (Behaviour::Stored, Rows::Stored) => 1,
            (Behaviour::Wheel { .. }, Rows::Read) => 1,
            (Behaviour::Wheel { write: Some(_), .. }, Rows::Written) => 1,
            _ => 0,
        };
        i += 1;
    }
    n
}

/// The size in bytes of a row's value.
const fn size(o: &AppObject) -> u8 {
    match o.data_type.size() {
        Some(n) => n as u8,
        None => panic!("an application object is a number"),
    }
}

/// One stored parameter: its object, where it sits in the stored section, and the values
/// within its limits that its write refuses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct StoredParameter {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Its first byte in the stored section (after the version byte).
    pub offset: u8,
    /// Its bytes there (little-endian), the size of its type.
    pub size: u8,
    /// [`AppObject::refused`].
    pub refused: u16,
}

/// How many parameters 0x1010 stores in the application's section.
pub const STORED_LEN: usize = count(Rows::Stored);

/// The stored parameters in the order of the application's section, from the rows marked
/// stored.
pub const STORED: [StoredParameter; STORED_LEN] = {
    let mut list = [StoredParameter {
        index: 0,
        sub: 0,
        offset: 0,
        size: 0,
        refused: 0,
    }; STORED_LEN];
    let mut k = 0;
    let mut offset = 0;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        let o = &APP_OBJECTS[i];
        if o.is_stored() {
            list[k] = StoredParameter {
                index: o.index,
                sub: o.sub,
                offset,
                size: size(o),
                refused: o.refused,
            };
            offset += size(o);
            k += 1;
        }
        i += 1;
    }
    list
};

/// The bytes of the stored parameters, after the version byte of the application's section.
pub const STORED_BYTES: usize = match STORED.last() {
    Some(p) => (p.offset + p.size) as usize,
    None => 0,
};

/// Where parameter `index:sub` sits in [`STORED`]; an object that is not one fails the build
/// where the answer is a constant.
pub(crate) const fn stored_slot(index: u16, sub: u8) -> usize {
    let mut k = 0;
    while k < STORED.len() {
        if STORED[k].index == index && STORED[k].sub == sub {
            return k;
        }
        k += 1;
    }
    panic!("not a stored parameter")
}

/// A value of the wheel as the device's read path looks it up at run time.
#[derive(Clone, Copy, Debug, Hash)]
pub(crate) struct WheelRead {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// The size of its type in bytes.
    pub size: u8,
    /// [`Behaviour::Wheel`]'s `read`.
    pub read: ReadFn,
}

/// The rows read from the wheel, without what only the compiler and the EDS need.
pub(crate) static WHEEL_READS: [WheelRead; count(Rows::Read)] = {
    let mut routes = [WheelRead {
        index: 0,
        sub: 0,
        size: 0,
        read: |_, _| 0,
    }; count(Rows::Read)];
    let mut k = 0;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        let o = &APP_OBJECTS[i];
        if let Behaviour::Wheel { read, .. } = o.behaviour {
            routes[k] = WheelRead {
                index: o.index,
                sub: o.sub,
                size: size(o),
                read,
            };
            k += 1;
        }
        i += 1;
    }
    routes
};

/// A value of the wheel as the device's write path looks it up at run time.
#[derive(Clone, Copy, Debug, Hash)]
pub(crate) struct WheelWrite {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// [`Behaviour::Wheel`]'s `enables_feed`.
    pub enables_feed: bool,
    /// [`Behaviour::Wheel`]'s `opens_session`.
    pub opens_session: bool,
    /// [`Behaviour::Wheel`]'s `write`.
    pub write: WriteFn,
}

/// The rows of the wheel that are written.
pub(crate) static WHEEL_WRITES: [WheelWrite; count(Rows::Written)] = {
    let mut routes = [WheelWrite {
        index: 0,
        sub: 0,
        enables_feed: false,
        opens_session: false,
        write: |_, _| Ok(()),
    }; count(Rows::Written)];
    let mut k = 0;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        let o = &APP_OBJECTS[i];
        if let Behaviour::Wheel {
            write: Some(write),
            enables_feed,
            opens_session,
            ..
        } = o.behaviour
        {
            routes[k] = WheelWrite {
                index: o.index,
                sub: o.sub,
                enables_feed,
                opens_session,
                write,
            };
            k += 1;
        }
        i += 1;
    }
    routes
};

/// The object of the unit-step byte in flight: the one row of [`Behaviour::UnitStep`].
pub(crate) const STEP_BYTE: (u16, u8) = {
    let mut found = None;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        let o = &APP_OBJECTS[i];
        if let Behaviour::UnitStep = o.behaviour {
            assert!(found.is_none(), "one unit-step byte");
            assert!(size(o) == 1, "the unit-step byte is one byte");
            found = Some((o.index, o.sub));
        }
        i += 1;
    }
    match found {
        Some(key) => key,
        None => panic!("no unit-step byte"),
    }
};

/// The digital outputs: the one row of [`Behaviour::Outputs`].
pub(crate) const OUTPUTS: (u16, u8) = {
    let mut found = None;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        let o = &APP_OBJECTS[i];
        if let Behaviour::Outputs = o.behaviour {
            assert!(found.is_none(), "one set of outputs");
            assert!(size(o) == 1, "the outputs are one byte");
            found = Some((o.index, o.sub));
        }
        i += 1;
    }
    match found {
        Some(key) => key,
        None => panic!("no outputs"),
    }
};

/// The device's uptime: the one row of [`Behaviour::Uptime`].
pub(crate) const UPTIME: (u16, u8) = {
    let mut found = None;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        let o = &APP_OBJECTS[i];
        if let Behaviour::Uptime = o.behaviour {
            assert!(found.is_none(), "one uptime");
            assert!(size(o) == 4, "the uptime is four bytes");
            found = Some((o.index, o.sub));
        }
        i += 1;
    }
    match found {
        Some(key) => key,
        None => panic!("no uptime"),
    }
};

/// How many rows are program download objects.
const PROGRAM_ROWS: usize = {
    let mut n = 0;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        if let Behaviour::Program(_) = APP_OBJECTS[i].behaviour {
            n += 1;
        }
        i += 1;
    }
    n
};

/// The program download objects as the device's read and write paths look them up:
/// `(index, sub, which)`.
pub(crate) static PROGRAM_OBJECTS: [(u16, u8, Program); PROGRAM_ROWS] = {
    let mut routes = [(0, 0, Program::Control); PROGRAM_ROWS];
    let mut k = 0;
    let mut i = 0;
    while i < APP_OBJECTS.len() {
        let o = &APP_OBJECTS[i];
        if let Behaviour::Program(p) = o.behaviour {
            routes[k] = (o.index, o.sub, p);
            k += 1;
        }
        i += 1;
    }
    routes
};

/// The whole dictionary; an unsorted or inconsistent table fails the build.
pub static OD: Od = Od::checked(&[&STANDARD, &HANDWHEEL]);
