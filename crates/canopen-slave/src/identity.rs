//! What the device is (0x1000, 0x1008-0x100A, 0x1018) and the defaults of its communication
//! parameters, both fed to [`standard_objects`](crate::standard_objects).

use crate::frame::cob;

/// Identity and description objects. The serial number (0x1018:04) is not here: it is only
/// known at run time and goes in [`Config`](crate::Config).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Identity {
    /// 0x1000: profile number in the low word, additional information in the high word.
    pub device_type: u32,
    /// 0x1018:01.
    pub vendor_id: u32,
    /// 0x1018:02.
    pub product_code: u32,
    /// 0x1018:03.
    pub revision: u32,
    /// 0x1008.
    pub device_name: &'static str,
    /// 0x1009.
    pub hardware_version: &'static str,
    /// 0x100A.
    pub software_version: &'static str,
}

/// Defaults of one transmit PDO (0x1800+n and 0x1A00+n).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TpdoDefaults {
    /// COB-ID without the node-ID (0x180 for TPDO1); set bit 31 to disable the PDO.
    pub cob_id_base: u32,
    /// 0 (SYNC acyclic), 1..=240 (every n-th SYNC), 254 or 255 (event-driven).
    pub transmission_type: u8,
    /// Minimum gap between two frames, 100 µs units.
    pub inhibit_100us: u16,
    /// Event timer, ms (0 = off).
    pub event_timer_ms: u16,
    /// Mapping entries `index << 16 | sub << 8 | bits`, at most 8.
    pub mapping: &'static [u32],
}

impl TpdoDefaults {
    /// TPDO `n` (1-based) of the pre-defined connection set: event-driven (255), no inhibit
    /// time, no event timer, nothing mapped.
    pub const fn predefined(n: u8) -> Self {
        Self {
            cob_id_base: (cob::TPDO1 as u32) + 0x100 * (n.saturating_sub(1) as u32),
            transmission_type: 255,
            inhibit_100us: 0,
            event_timer_ms: 0,
            mapping: &[],
        }
    }
}

/// Defaults of one receive PDO (0x1400+n and 0x1600+n).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RpdoDefaults {
    /// COB-ID without the node-ID (0x200 for RPDO1); set bit 31 to disable the PDO.
    pub cob_id_base: u32,
    /// 0..=240 (the data takes effect at the next SYNC), 254 or 255 (at once).
    pub transmission_type: u8,
    /// Deadline monitoring, ms (0 = off): no frame within it in Operational is EMCY 0x8250.
    pub event_timer_ms: u16,
    /// Mapping entries `index << 16 | sub << 8 | bits`, at most 8.
    pub mapping: &'static [u32],
}

impl RpdoDefaults {
    /// RPDO `n` (1-based) of the pre-defined connection set: 0x200 + 0x100 * (n - 1), acting
    /// at once (255), no deadline monitoring, nothing mapped.
    pub const fn predefined(n: u8) -> Self {
        Self {
            cob_id_base: (cob::RPDO1 as u32) + 0x100 * (n.saturating_sub(1) as u32),
            transmission_type: 255,
            event_timer_ms: 0,
            mapping: &[],
        }
    }
}

/// Defaults of the engine-owned communication parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CommDefaults {
    /// 0x1017 producer heartbeat time, ms (0 = off).
    pub heartbeat_ms: u16,
    /// 0x1016:01..02 consumer entries (`node << 16 | ms`).
    pub heartbeat_consumers: [u32; 2],
    /// 0x1015 EMCY inhibit time, 100 µs units.
    pub emcy_inhibit_100us: u16,
    /// RPDO1.
    pub rpdo: [RpdoDefaults; 1],
    /// TPDO1 and TPDO2.
    pub tpdo: [TpdoDefaults; 2],
}

impl CommDefaults {
    /// Heartbeat every second, no consumers, no EMCY inhibit, pre-defined PDOs.
    pub const DEFAULT: Self = Self {
        heartbeat_ms: 1000,
        heartbeat_consumers: [0, 0],
        emcy_inhibit_100us: 0,
        rpdo: [RpdoDefaults::predefined(1)],
        tpdo: [TpdoDefaults::predefined(1), TpdoDefaults::predefined(2)],
    };
}
