//! The handwheel's object dictionary: the engine's communication objects plus the
//! handwheel's own. These indices are the device's public interface; `eds/handwheel.eds`
//! describes exactly this table (a host test keeps the two in step).

use canopen_slave::{
    standard_objects, Access, CommDefaults, DataType, Identity, Od, OdEntry, TpdoDefaults,
    STANDARD_OBJECTS,
};

/// Feed enable: 1 = handwheel mode on. U8 rw, 0..1, default 0.
pub const FEED_ENABLE: u16 = 0x2000;
/// Feed format: 0 = feed record, 1 = the paper's unit-step stream. U8 rw, 0..1, default 0.
pub const FEED_FORMAT: u16 = 0x2001;
/// Selection record: sub 1 axis, sub 2 multiplier, sub 3 epoch (all U8 ro, mappable).
pub const SELECTION: u16 = 0x2010;
/// Encoder record: sub 1 raw count (I32), sub 2 illegal transitions (U32), sub 3 counts per
/// detent (U8 rw 1/2/4), sub 4 invert (U8 rw 0/1).
pub const ENCODER: u16 = 0x2020;
/// Feed status: flags in bits 0-4, the epoch's low three bits in 5-7 (U8 ro, mappable).
pub const FEED_STATUS: u16 = 0x2030;
/// Feed sequence: +1 per feed record (TPDO1) sent and per loss, +8 at a break (U8 ro,
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

/// TPDO1's default mapping: the 8-byte feed record of `handwheel_core::pdo`.
pub const FEED_RECORD_MAPPING: [u32; 5] = [
    map(POSITION_VALUE, 0, 32),
    map(SELECTION, 1, 8),
    map(SELECTION, 2, 8),
    map(FEED_STATUS, 0, 8),
    map(FEED_SEQUENCE, 0, 8),
];

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

const HANDWHEEL: &[OdEntry] = {
    use Access::{Ro, Rw};
    use DataType::{I32, U16, U32, U8};
    &[
        OdEntry::app(FEED_ENABLE, 0, U8, Rw).range(0, 1),
        OdEntry::app(FEED_FORMAT, 0, U8, Rw).range(0, 1),
        OdEntry::highest_sub(SELECTION, 3),
        OdEntry::app(SELECTION, 1, U8, Ro).mappable(),
        OdEntry::app(SELECTION, 2, U8, Ro).mappable(),
        OdEntry::app(SELECTION, 3, U8, Ro).mappable(),
        OdEntry::highest_sub(ENCODER, 4),
        OdEntry::app(ENCODER, 1, I32, Ro).mappable(),
        OdEntry::app(ENCODER, 2, U32, Ro).mappable(),
        OdEntry::app(ENCODER, 3, U8, Rw).range(1, 4),
        OdEntry::app(ENCODER, 4, U8, Rw).range(0, 1),
        OdEntry::app(FEED_STATUS, 0, U8, Ro).mappable(),
        OdEntry::app(FEED_SEQUENCE, 0, U8, Ro).mappable(),
        OdEntry::app(UNIT_STEP, 0, U8, Ro).mappable(),
        OdEntry::highest_sub(FEED_DIAGNOSTICS, 3),
        OdEntry::app(FEED_DIAGNOSTICS, 1, U32, Ro),
        OdEntry::app(FEED_DIAGNOSTICS, 2, U32, Ro),
        OdEntry::app(FEED_DIAGNOSTICS, 3, U16, Rw).range(1, MAX_BACKLOG_BOUND as i64),
        OdEntry::app(POSITION_VALUE, 0, I32, Ro).mappable(),
    ]
};

/// The whole dictionary; an unsorted or inconsistent table fails the build.
pub static OD: Od = Od::checked(&[&STANDARD, HANDWHEEL]);
