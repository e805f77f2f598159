//! The communication objects (0x1000-0x1FFF) and the checked paths to every object of the
//! dictionary.
//!
//! Each communication object is one row of [`OBJECTS`]: the indices it covers, its entries
//! (type, access, where the default comes from, whether 0x1010 stores it), and how it reads,
//! checks and writes, and restores (a table default or a stored value) itself. From the rows
//! come the dictionary's standard part ([`standard_objects`], with the defaults the device
//! declares), the blob layout ([`STORED`]) and the run-time routes ([`ROUTES`]). Adding a
//! communication object is adding its row.

pub(crate) mod params;

use super::Application;
use crate::abort::SdoAbort;
use crate::cob_id::{check_cob_id_write, COB_INVALID};
use crate::emcy::Emcy;
use crate::frame::{cob, NodeId, MAX_STANDARD_ID};
use crate::heartbeat::Heartbeat;
use crate::identity::{CommDefaults, Identity};
use crate::mapping::MAX_MAPPED;
use crate::nmt::NmtState;
use crate::od::{Access, DataType, ObjectCode, Od, OdEntry, Value};
use crate::rpdo::{Rpdo, RPDOS};
use crate::storage::Storage;
use crate::sync::SyncConsumer;
use crate::time::Instant;
use crate::tpdo::{Tpdo, NO_RTR, TPDOS};

/// The NMT state and the services behind the communication objects.
#[derive(Clone, Debug, PartialEq, Hash)]
pub(super) struct Comm {
    pub(super) od: Od,
    /// The active node-ID; `None` while unconfigured (the NMT state is then Initialising).
    pub(super) node: Option<NodeId>,
    /// 0x1018:04.
    pub(super) serial: u32,
    /// Changed only by `Device::set_state`.
    pub(super) state: NmtState,
    pub(super) heartbeat: Heartbeat,
    pub(super) sync: SyncConsumer,
    pub(super) rpdos: [Rpdo; RPDOS],
    pub(super) tpdos: [Tpdo; TPDOS],
    pub(super) emcy: Emcy,
    /// 0x1201:1..3, the second SDO server's parameters: COB-ID client to server, COB-ID
    /// server to client, node-ID of the client. Not stored: every initialisation sets
    /// [`SDO2_DEFAULTS`].
    pub(super) sdo2: [u32; 3],
}

/// 0x1201's defaults: both COB-IDs not valid (bit 31), no client node-ID.
pub(super) const SDO2_DEFAULTS: [u32; 3] = [COB_INVALID, COB_INVALID, 0];

/// A stored value the checked write path refused at a restore: the object keeps its
/// default.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) struct Refused {
    pub(super) index: u16,
    pub(super) sub: u8,
    pub(super) abort: SdoAbort,
}

/// Whether `(index, sub)` is a COB-ID that may not change while valid (EMCY, PDOs): a
/// restore gives these up first and sets them last, as a master re-configuring them does.
fn guarded_cob_id(index: u16, sub: u8) -> bool {
    index == 0x1014 || (matches!(index & 0xFE00, 0x1400 | 0x1800) && sub == 1)
}

/// Whether `index` is a PDO mapping object.
fn mapping_object(index: u16) -> bool {
    matches!(index & 0xFE00, 0x1600 | 0x1A00)
}

/// What a checked write may need besides the objects.
pub(super) struct WriteCtx<'a> {
    pub(super) now: Instant,
    /// For 0x1010 (the application's parameters) and 0x1011 (whether it may store now).
    pub(super) app: &'a mut dyn Application,
    /// For 0x1010 and 0x1011.
    pub(super) storage: &'a mut dyn Storage,
}

/// Reads sub-index `sub` of object `index`.
type Read = fn(&Comm, u16, u8) -> Result<u32, SdoAbort>;
/// Writes a value the dictionary's entry has checked (type and range), after the object's
/// own checks; changes nothing on failure.
type Write = fn(&mut Comm, &mut WriteCtx<'_>, u16, u8, u32) -> Result<(), SdoAbort>;
/// Sets a table default or a stored value, unchecked.
type Restore = fn(&mut Comm, u16, u8, u32, Instant);

/// One communication object, or one per PDO for the PDO parameter ranges: what CiA 301 calls
/// it, its sub-indices and its behaviour. Its name and object code are for configuration
/// tools (`cargo xtask eds` prints them); only its behaviour reaches the firmware image,
/// through `ROUTES`.
pub struct CommObject {
    first: u16,
    last: u16,
    group: Group,
    /// CiA 301's name; a PDO range's carries its PDO's number after the first word
    /// ([`ObjectName`]).
    name: &'static str,
    code: ObjectCode,
    /// Its sub-indices (of each PDO's object, for the PDO ranges), as the dictionary lists
    /// them.
    entries: &'static [CommEntry],
    read: Read,
    write: Write,
    restore: Restore,
}

impl CommObject {
    /// The name of object `index`, one of this row's.
    pub const fn name(&self, index: u16) -> ObjectName {
        ObjectName {
            text: self.name,
            number: if matches!(self.group, Group::Single) {
                None
            } else {
                Some(index.wrapping_sub(self.first).wrapping_add(1))
            },
        }
    }

    /// VAR, ARRAY or RECORD.
    pub const fn code(&self) -> ObjectCode {
        self.code
    }

    /// Sub-index `sub`, if the object has it.
    pub fn entry(&self, sub: u8) -> Option<&'static CommEntry> {
        self.entries.iter().find(|e| e.sub == sub)
    }
}

/// The name of a communication object: CiA 301's, with the PDO's number after the first
/// word for the objects of one PDO ("TPDO communication parameter" of the first TPDO is
/// "TPDO1 communication parameter").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ObjectName {
    text: &'static str,
    number: Option<u16>,
}

impl core::fmt::Display for ObjectName {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match (self.number, self.text.split_once(' ')) {
            (Some(n), Some((first, rest))) => write!(f, "{first}{n} {rest}"),
            (Some(n), None) => write!(f, "{}{n}", self.text),
            (None, _) => f.write_str(self.text),
        }
    }
}

/// Whether a row is one object or a PDO range's, one object per PDO of its direction.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Group {
    Single,
    Rpdo,
    Tpdo,
}

impl Group {
    /// How many objects a row of this group stands for.
    const fn objects(self) -> usize {
        match self {
            Self::Single => 1,
            Self::Rpdo => RPDOS,
            Self::Tpdo => TPDOS,
        }
    }
}

/// The groups in the order their stored parameters were added to the blob: a later group's
/// go after an earlier one's, so that a blob of an older layout is a prefix of today's.
const BLOB_ORDER: [Group; 3] = [Group::Single, Group::Tpdo, Group::Rpdo];

/// The communication object of `index` (the PDO ranges' row for any of their indices), for
/// configuration tools: the engine finds its objects through `ROUTES`.
pub fn comm_object(index: u16) -> Option<&'static CommObject> {
    OBJECTS.iter().find(|o| (o.first..=o.last).contains(&index))
}

/// Where the value of a communication entry comes from: a number CiA 301 or the engine
/// fixes, or what the device declares ([`Identity`], [`CommDefaults`]; a PDO range's entries
/// take their PDO's [`RpdoDefaults`](crate::RpdoDefaults) or
/// [`TpdoDefaults`](crate::TpdoDefaults)).
#[derive(Clone, Copy)]
enum Source {
    Fixed(u32),
    DeviceType,
    VendorId,
    ProductCode,
    Revision,
    DeviceName,
    HardwareVersion,
    SoftwareVersion,
    EmcyInhibit,
    /// Consumer heartbeat entry `n` (0-based).
    Consumer(usize),
    Heartbeat,
    RpdoCobId,
    RpdoType,
    RpdoEventTimer,
    TpdoCobId,
    TpdoType,
    TpdoInhibit,
    TpdoEventTimer,
    MappedCount,
    /// Mapping entry `n` (0-based), 0 past the default mapping.
    Mapped(usize),
}

/// How an entry's value is kept: fixed at build time, or a parameter the engine owns (with
/// the node-ID added to its default, for COB-IDs).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Constant,
    Parameter,
    ParameterPlusNodeId,
}

/// One sub-index of a communication object.
#[derive(Clone, Copy)]
pub struct CommEntry {
    sub: u8,
    name: &'static str,
    data_type: DataType,
    access: Access,
    kind: Kind,
    source: Source,
    /// A parameter 0x1010 stores.
    stored: bool,
    hex: bool,
    limits: Option<(i64, i64)>,
}

impl CommEntry {
    /// A value fixed at build time.
    const fn constant(sub: u8, name: &'static str, data_type: DataType, source: Source) -> Self {
        Self {
            sub,
            name,
            data_type,
            access: Access::Const,
            kind: Kind::Constant,
            source,
            stored: false,
            hex: false,
            limits: None,
        }
    }

    /// Sub-index 0 of a record or array: its highest sub-index.
    const fn highest(highest: u8) -> Self {
        Self::constant(
            0,
            "Highest sub-index supported",
            DataType::U8,
            Source::Fixed(highest as u32),
        )
    }

    /// A parameter the engine owns, not stored.
    const fn parameter(
        sub: u8,
        name: &'static str,
        data_type: DataType,
        access: Access,
        source: Source,
    ) -> Self {
        Self {
            access,
            kind: Kind::Parameter,
            ..Self::constant(sub, name, data_type, source)
        }
    }

    /// Stored by 0x1010.
    const fn stored(mut self) -> Self {
        self.stored = true;
        self
    }

    /// A COB-ID whose default is relative to the node-ID.
    const fn plus_node_id(mut self) -> Self {
        self.kind = Kind::ParameterPlusNodeId;
        self
    }

    /// Written in hexadecimal by configuration tools: an identifier or a code.
    const fn hex(mut self) -> Self {
        self.hex = true;
        self
    }

    /// The values the object's own write check lets through, narrower than its type's.
    const fn limits(mut self, low: i64, high: i64) -> Self {
        self.limits = Some((low, high));
        self
    }

    /// CiA 301's name of the sub-index.
    pub const fn name(&self) -> &'static str {
        self.name
    }

    /// Whether configuration tools write the value in hexadecimal (identifiers, codes,
    /// mapping entries); a node-ID-relative default is always written so.
    pub const fn is_hex(&self) -> bool {
        self.hex
    }

    /// The values a write may set when the object's own check is narrower than its type
    /// (the table's range covers application objects only): a configuration tool's
    /// LowLimit/HighLimit.
    pub const fn write_limits(&self) -> Option<(i64, i64)> {
        self.limits
    }

    /// The dictionary's entry at `index` (of PDO `pdo`, 0-based, of the row's `group`).
    const fn od_entry(
        &self,
        index: u16,
        id: &Identity,
        d: &CommDefaults,
        group: Group,
        pdo: usize,
    ) -> OdEntry {
        let mapping = match group {
            Group::Rpdo => d.rpdo[pdo].mapping,
            Group::Tpdo => d.tpdo[pdo].mapping,
            Group::Single => &[],
        };
        let text = match self.source {
            Source::DeviceName => Some(id.device_name),
            Source::HardwareVersion => Some(id.hardware_version),
            Source::SoftwareVersion => Some(id.software_version),
            _ => None,
        };
        if let Some(text) = text {
            return OdEntry::string(index, self.sub, text);
        }
        let value = match self.source {
            Source::Fixed(v) => v,
            Source::DeviceType => id.device_type,
            Source::VendorId => id.vendor_id,
            Source::ProductCode => id.product_code,
            Source::Revision => id.revision,
            Source::EmcyInhibit => d.emcy_inhibit_100us as u32,
            Source::Consumer(n) => d.heartbeat_consumers[n],
            Source::Heartbeat => d.heartbeat_ms as u32,
            Source::RpdoCobId => d.rpdo[pdo].cob_id_base,
            Source::RpdoType => d.rpdo[pdo].transmission_type as u32,
            Source::RpdoEventTimer => d.rpdo[pdo].event_timer_ms as u32,
            // Bit 30 reads 1 whatever is written (no RTR): the default says so too.
            Source::TpdoCobId => d.tpdo[pdo].cob_id_base | NO_RTR,
            Source::TpdoType => d.tpdo[pdo].transmission_type as u32,
            Source::TpdoInhibit => d.tpdo[pdo].inhibit_100us as u32,
            Source::TpdoEventTimer => d.tpdo[pdo].event_timer_ms as u32,
            Source::MappedCount => mapping.len() as u32,
            Source::Mapped(n) if n < mapping.len() => mapping[n],
            Source::Mapped(_) => 0,
            // Handled above.
            Source::DeviceName | Source::HardwareVersion | Source::SoftwareVersion => 0,
        };
        let value = match self.kind {
            Kind::Constant => Value::Const(value),
            Kind::Parameter => Value::Comm(value),
            Kind::ParameterPlusNodeId => Value::CommPlusNodeId(value),
        };
        OdEntry::new(index, self.sub, self.data_type, self.access, value)
    }
}

/// `read` of an object whose entries are all constants (the table answers them).
fn constants_only(_: &Comm, _: u16, _: u8) -> Result<u32, SdoAbort> {
    Err(SdoAbort::NoObject)
}

/// `write` of an object no write reaches (its entries are read-only).
fn read_only(_: &mut Comm, _: &mut WriteCtx<'_>, _: u16, _: u8, _: u32) -> Result<(), SdoAbort> {
    Err(SdoAbort::ReadOnly)
}

/// `restore` of an object whose value is not a parameter (a status, a command).
fn not_a_parameter(_: &mut Comm, _: u16, _: u8, _: u32, _: Instant) {}

/// `read` of the EMCY objects (0x1003, 0x1014, 0x1015).
fn emcy_read(c: &Comm, index: u16, sub: u8) -> Result<u32, SdoAbort> {
    c.emcy.read(index, sub)
}

/// `write` of 0x1003 and 0x1015 (0x1014 checks its COB-ID first).
fn emcy_write(
    c: &mut Comm,
    _: &mut WriteCtx<'_>,
    index: u16,
    sub: u8,
    v: u32,
) -> Result<(), SdoAbort> {
    c.emcy.write(index, sub, v)
}

/// `restore` of 0x1014 and 0x1015.
fn emcy_restore(c: &mut Comm, index: u16, _: u8, v: u32, _: Instant) {
    c.emcy.set(index, v);
}

/// `read` of 0x1010 and 0x1011: the capability, bit 0 (on command).
fn on_command(_: &Comm, _: u16, _: u8) -> Result<u32, SdoAbort> {
    Ok(1)
}

/// The entries of a PDO mapping object, either direction.
const MAPPING_ENTRIES: &[CommEntry] = {
    use Access::Rw;
    use CommEntry as E;
    use DataType::{U32, U8};
    &[
        // No table limit: the mapping's own check refuses a count above its entries with
        // 0x06040042, as CANopenNode does (a limit would answer 0x06090031 first).
        E::parameter(0, "Number of mapped objects", U8, Rw, Source::MappedCount).stored(),
        E::parameter(1, "Mapped object 1", U32, Rw, Source::Mapped(0))
            .hex()
            .stored(),
        E::parameter(2, "Mapped object 2", U32, Rw, Source::Mapped(1))
            .hex()
            .stored(),
        E::parameter(3, "Mapped object 3", U32, Rw, Source::Mapped(2))
            .hex()
            .stored(),
        E::parameter(4, "Mapped object 4", U32, Rw, Source::Mapped(3))
            .hex()
            .stored(),
        E::parameter(5, "Mapped object 5", U32, Rw, Source::Mapped(4))
            .hex()
            .stored(),
        E::parameter(6, "Mapped object 6", U32, Rw, Source::Mapped(5))
            .hex()
            .stored(),
        E::parameter(7, "Mapped object 7", U32, Rw, Source::Mapped(6))
            .hex()
            .stored(),
        E::parameter(8, "Mapped object 8", U32, Rw, Source::Mapped(7))
            .hex()
            .stored(),
    ]
};

/// The communication objects, by index. The engine looks them up in [`ROUTES`], the rows
/// with behaviour without what only the compiler and configuration tools need.
const OBJECTS: &[CommObject] = {
    use Access::{Ro, Rw};
    use CommEntry as E;
    use DataType::{VisibleString, U16, U32, U8};
    use ObjectCode::{Array, Record, Var};
    &[
        CommObject {
            first: 0x1000,
            last: 0x1000,
            group: Group::Single,
            name: "Device type",
            code: Var,
            entries: &[E::constant(0, "Device type", U32, Source::DeviceType).hex()],
            read: constants_only,
            write: read_only,
            restore: not_a_parameter,
        },
        CommObject {
            first: 0x1001,
            last: 0x1001,
            group: Group::Single,
            name: "Error register",
            code: Var,
            entries: &[E::parameter(0, "Error register", U8, Ro, Source::Fixed(0))],
            read: |c, _, _| Ok(c.emcy.error_register().into()),
            write: read_only,
            restore: not_a_parameter,
        },
        // The error history: writing 0 to sub 0 clears it.
        CommObject {
            first: 0x1003,
            last: 0x1003,
            group: Group::Single,
            name: "Pre-defined error field",
            code: Array,
            entries: &[
                E::parameter(0, "Number of errors", U8, Rw, Source::Fixed(0)),
                E::parameter(1, "Standard error field 1", U32, Ro, Source::Fixed(0)),
                E::parameter(2, "Standard error field 2", U32, Ro, Source::Fixed(0)),
                E::parameter(3, "Standard error field 3", U32, Ro, Source::Fixed(0)),
                E::parameter(4, "Standard error field 4", U32, Ro, Source::Fixed(0)),
            ],
            read: emcy_read,
            write: emcy_write,
            restore: not_a_parameter,
        },
        CommObject {
            first: 0x1005,
            last: 0x1005,
            group: Group::Single,
            name: "COB-ID SYNC",
            code: Var,
            entries: &[E::parameter(0, "COB-ID SYNC", U32, Rw, Source::Fixed(0x80))
                .hex()
                .stored()],
            read: |c, _, _| Ok(c.sync.cob_id()),
            write: |c, _, _, _, v| {
                c.check_cob_id(CobSlot::Sync, v)?;
                c.sync.set(v);
                Ok(())
            },
            restore: |c, _, _, v, _| c.sync.set(v),
        },
        CommObject {
            first: 0x1008,
            last: 0x1008,
            group: Group::Single,
            name: "Manufacturer device name",
            code: Var,
            entries: &[E::constant(
                0,
                "Manufacturer device name",
                VisibleString,
                Source::DeviceName,
            )],
            read: constants_only,
            write: read_only,
            restore: not_a_parameter,
        },
        CommObject {
            first: 0x1009,
            last: 0x1009,
            group: Group::Single,
            name: "Manufacturer hardware version",
            code: Var,
            entries: &[E::constant(
                0,
                "Manufacturer hardware version",
                VisibleString,
                Source::HardwareVersion,
            )],
            read: constants_only,
            write: read_only,
            restore: not_a_parameter,
        },
        CommObject {
            first: 0x100A,
            last: 0x100A,
            group: Group::Single,
            name: "Manufacturer software version",
            code: Var,
            entries: &[E::constant(
                0,
                "Manufacturer software version",
                VisibleString,
                Source::SoftwareVersion,
            )],
            read: constants_only,
            write: read_only,
            restore: not_a_parameter,
        },
        // Each sub-index reads 1: it saves on command (CiA 301).
        CommObject {
            first: 0x1010,
            last: 0x1010,
            group: Group::Single,
            name: "Store parameters",
            code: Array,
            entries: &[
                E::highest(3),
                E::parameter(1, "Save all parameters", U32, Rw, Source::Fixed(1)),
                E::parameter(
                    2,
                    "Save communication parameters",
                    U32,
                    Rw,
                    Source::Fixed(1),
                ),
                E::parameter(3, "Save application parameters", U32, Rw, Source::Fixed(1)),
            ],
            read: on_command,
            write: |c, ctx, _, sub, v| params::save(c, ctx, sub, v),
            restore: not_a_parameter,
        },
        // Each sub-index reads 1: it restores on command (CiA 301).
        CommObject {
            first: 0x1011,
            last: 0x1011,
            group: Group::Single,
            name: "Restore default parameters",
            code: Array,
            entries: &[
                E::highest(3),
                E::parameter(
                    1,
                    "Restore all default parameters",
                    U32,
                    Rw,
                    Source::Fixed(1),
                ),
                E::parameter(
                    2,
                    "Restore communication default parameters",
                    U32,
                    Rw,
                    Source::Fixed(1),
                ),
                E::parameter(
                    3,
                    "Restore application default parameters",
                    U32,
                    Rw,
                    Source::Fixed(1),
                ),
            ],
            read: on_command,
            write: |_, ctx, _, sub, v| params::forget(ctx, sub, v),
            restore: not_a_parameter,
        },
        CommObject {
            first: 0x1014,
            last: 0x1014,
            group: Group::Single,
            name: "COB-ID EMCY",
            code: Var,
            entries: &[E::parameter(0, "COB-ID EMCY", U32, Rw, Source::Fixed(0x80))
                .plus_node_id()
                .stored()],
            read: emcy_read,
            write: |c, _, index, sub, v| {
                c.check_cob_id(CobSlot::Emcy, v)?;
                c.emcy.write(index, sub, v)
            },
            restore: emcy_restore,
        },
        CommObject {
            first: 0x1015,
            last: 0x1015,
            group: Group::Single,
            name: "Inhibit time EMCY",
            code: Var,
            entries: &[E::parameter(0, "Inhibit time EMCY", U16, Rw, Source::EmcyInhibit).stored()],
            read: emcy_read,
            write: emcy_write,
            restore: emcy_restore,
        },
        CommObject {
            first: 0x1016,
            last: 0x1016,
            group: Group::Single,
            name: "Consumer heartbeat time",
            code: Array,
            entries: &[
                E::highest(2),
                E::parameter(1, "Consumer heartbeat time 1", U32, Rw, Source::Consumer(0)).stored(),
                E::parameter(2, "Consumer heartbeat time 2", U32, Rw, Source::Consumer(1)).stored(),
            ],
            read: |c, _, sub| c.heartbeat.consumer(sub),
            write: |c, _, _, sub, v| match c.node {
                Some(own) => c.heartbeat.write_consumer(sub, v, own),
                None => Err(SdoAbort::DeviceState),
            },
            restore: |c, _, sub, v, _| c.heartbeat.set_consumer(sub, v),
        },
        // Typed U16 in the table, so the truncations are lossless.
        CommObject {
            first: 0x1017,
            last: 0x1017,
            group: Group::Single,
            name: "Producer heartbeat time",
            code: Var,
            entries: &[
                E::parameter(0, "Producer heartbeat time", U16, Rw, Source::Heartbeat).stored(),
            ],
            read: |c, _, _| Ok(c.heartbeat.producer_ms().into()),
            write: |c, ctx, _, _, v| {
                c.heartbeat.set_producer(v as u16, ctx.now);
                Ok(())
            },
            restore: |c, _, _, v, now| c.heartbeat.set_producer(v as u16, now),
        },
        // The serial number is read; the other entries are constants.
        CommObject {
            first: 0x1018,
            last: 0x1018,
            group: Group::Single,
            name: "Identity object",
            code: Record,
            entries: &[
                E::highest(4),
                E::constant(1, "Vendor-ID", U32, Source::VendorId).hex(),
                E::constant(2, "Product code", U32, Source::ProductCode).hex(),
                E::constant(3, "Revision number", U32, Source::Revision).hex(),
                E::parameter(4, "Serial number", U32, Ro, Source::Fixed(0)),
            ],
            read: |c, _, _| Ok(c.serial),
            write: read_only,
            restore: not_a_parameter,
        },
        // The second SDO server (CiA 301 allows 0x1201..0x127F; the device has one). Its
        // COB-IDs follow the rules of the other COB-IDs; not stored.
        CommObject {
            first: 0x1201,
            last: 0x1201,
            group: Group::Single,
            name: "SDO server parameter",
            code: Record,
            entries: &[
                E::highest(3),
                E::parameter(
                    1,
                    "COB-ID client to server",
                    U32,
                    Rw,
                    Source::Fixed(COB_INVALID),
                )
                .hex(),
                E::parameter(
                    2,
                    "COB-ID server to client",
                    U32,
                    Rw,
                    Source::Fixed(COB_INVALID),
                )
                .hex(),
                E::parameter(3, "Node-ID of the SDO client", U8, Rw, Source::Fixed(0))
                    .limits(0, 127),
            ],
            // The table has sub-indices 1..=3 only.
            read: |c, _, sub| {
                let n = usize::from(sub).wrapping_sub(1);
                c.sdo2.get(n).copied().ok_or(SdoAbort::NoSubIndex)
            },
            write: |c, _, _, sub, v| {
                match sub {
                    1 | 2 => c.check_cob_id(CobSlot::Sdo(usize::from(sub - 1)), v)?,
                    _ if v > 127 => return Err(SdoAbort::ValueTooHigh),
                    _ => {}
                }
                c.set_sdo2(sub, v);
                Ok(())
            },
            restore: |c, _, sub, v, _| c.set_sdo2(sub, v),
        },
        CommObject {
            first: 0x1400,
            last: 0x15FF,
            group: Group::Rpdo,
            name: "RPDO communication parameter",
            code: Record,
            entries: &[
                E::highest(5),
                E::parameter(1, "COB-ID used by RPDO", U32, Rw, Source::RpdoCobId)
                    .plus_node_id()
                    .stored(),
                E::parameter(2, "Transmission type", U8, Rw, Source::RpdoType).stored(),
                E::parameter(5, "Event timer", U16, Rw, Source::RpdoEventTimer).stored(),
            ],
            read: |c, index, sub| c.rpdo(index - 0x1400)?.read_comm(sub),
            write: |c, _, index, sub, v| {
                let n = index - 0x1400;
                c.rpdo(n)?;
                if sub == 1 {
                    c.check_cob_id(CobSlot::Rpdo(usize::from(n)), v)?;
                }
                c.rpdo_mut(n)?.write_comm(sub, v)
            },
            restore: |c, index, sub, v, _| {
                if let Ok(r) = c.rpdo_mut(index - 0x1400) {
                    r.set_comm(sub, v);
                }
            },
        },
        CommObject {
            first: 0x1600,
            last: 0x17FF,
            group: Group::Rpdo,
            name: "RPDO mapping parameter",
            code: Record,
            entries: MAPPING_ENTRIES,
            read: |c, index, sub| c.rpdo(index - 0x1600)?.read_mapping(sub),
            write: |c, _, index, sub, v| {
                let od = c.od;
                c.rpdo_mut(index - 0x1600)?.write_mapping(sub, v, &od)
            },
            restore: |c, index, sub, v, _| {
                if let Ok(r) = c.rpdo_mut(index - 0x1600) {
                    r.set_mapping(sub, v);
                }
            },
        },
        CommObject {
            first: 0x1800,
            last: 0x19FF,
            group: Group::Tpdo,
            name: "TPDO communication parameter",
            code: Record,
            entries: &[
                E::highest(5),
                E::parameter(1, "COB-ID used by TPDO", U32, Rw, Source::TpdoCobId)
                    .plus_node_id()
                    .stored(),
                E::parameter(2, "Transmission type", U8, Rw, Source::TpdoType).stored(),
                E::parameter(3, "Inhibit time", U16, Rw, Source::TpdoInhibit).stored(),
                E::parameter(5, "Event timer", U16, Rw, Source::TpdoEventTimer).stored(),
            ],
            read: |c, index, sub| c.tpdo(index - 0x1800)?.read_comm(sub),
            write: |c, ctx, index, sub, v| {
                let n = index - 0x1800;
                c.tpdo(n)?;
                if sub == 1 {
                    c.check_cob_id(CobSlot::Tpdo(usize::from(n)), v)?;
                }
                let operational = c.state == NmtState::Operational;
                c.tpdo_mut(n)?.write_comm(sub, v, ctx.now, operational)
            },
            restore: |c, index, sub, v, _| {
                if let Ok(t) = c.tpdo_mut(index - 0x1800) {
                    t.set_comm(sub, v);
                }
            },
        },
        CommObject {
            first: 0x1A00,
            last: 0x1BFF,
            group: Group::Tpdo,
            name: "TPDO mapping parameter",
            code: Record,
            entries: MAPPING_ENTRIES,
            read: |c, index, sub| c.tpdo(index - 0x1A00)?.read_mapping(sub),
            write: |c, _, index, sub, v| {
                let od = c.od;
                c.tpdo_mut(index - 0x1A00)?.write_mapping(sub, v, &od)
            },
            restore: |c, index, sub, v, _| {
                if let Ok(t) = c.tpdo_mut(index - 0x1A00) {
                    t.set_mapping(sub, v);
                }
            },
        },
    ]
};

/// A VAR row is its one sub-index 0; an ARRAY or RECORD row starts with the sub-index 0 that
/// counts the others.
const _: () = {
    let mut i = 0;
    while i < OBJECTS.len() {
        let o = &OBJECTS[i];
        let var = matches!(o.code, ObjectCode::Var);
        assert!(
            o.entries[0].sub == 0 && (o.entries.len() == 1) == var,
            "a VAR is one sub-index 0, an ARRAY or RECORD counts its sub-indices in sub-index 0"
        );
        i += 1;
    }
};

/// How many sub-indices [`standard_objects`] lists: one per entry of a single object, one
/// per entry and PDO of a PDO range.
pub const STANDARD_OBJECTS: usize = {
    let mut len = 0;
    let mut i = 0;
    while i < OBJECTS.len() {
        let o = &OBJECTS[i];
        len += o.entries.len() * o.group.objects();
        i += 1;
    }
    len
};

/// The communication profile area (0x1000-0x1FFF) the engine implements, ready to be the
/// first part of an application's [`Od`]: the entries of the engine's object rows, with the
/// defaults the device declares: 0x1000, 0x1001, 0x1003 (4 entries), 0x1005, 0x1008-0x100A,
/// 0x1010, 0x1011, 0x1014, 0x1015, 0x1016 (2 consumers), 0x1017, 0x1018, 0x1201 (a second
/// SDO server), RPDO1 (0x1400, 0x1600), TPDO1/2 (0x1800/0x1801, 0x1A00/0x1A01).
pub const fn standard_objects(id: &Identity, d: &CommDefaults) -> [OdEntry; STANDARD_OBJECTS] {
    let mut pdo = 0;
    while pdo < d.tpdo.len() {
        assert!(
            d.tpdo[pdo].mapping.len() <= MAX_MAPPED,
            "a PDO maps at most 8 objects"
        );
        pdo += 1;
    }
    pdo = 0;
    while pdo < d.rpdo.len() {
        assert!(
            d.rpdo[pdo].mapping.len() <= MAX_MAPPED,
            "a PDO maps at most 8 objects"
        );
        pdo += 1;
    }
    let mut list = [OdEntry::highest_sub(0, 0); STANDARD_OBJECTS];
    let mut k = 0;
    let mut i = 0;
    while i < OBJECTS.len() {
        let o = &OBJECTS[i];
        let mut pdo = 0;
        while pdo < o.group.objects() {
            let mut e = 0;
            while e < o.entries.len() {
                // Below 0x200 PDOs per range, so the offset fits.
                list[k] = o.entries[e].od_entry(o.first + pdo as u16, id, d, o.group, pdo);
                k += 1;
                e += 1;
            }
            pdo += 1;
        }
        i += 1;
    }
    list
}

/// How many parameters 0x1010 stores.
pub(crate) const STORED_LEN: usize = stored_len(BLOB_ORDER.len());

/// How many of them blob version 1 holds: those before the RPDO's.
pub(crate) const STORED_V1_LEN: usize = stored_len(2);

/// The parameters 0x1010 stores, in the order of the blob's communication section: group by
/// group in [`BLOB_ORDER`] (the single objects' stored sub-indices in table order, then PDO
/// by PDO the TPDO ranges', then the RPDO ranges').
pub(crate) const STORED: [(u16, u8); STORED_LEN] = stored_list();

/// How many parameters the first `groups` groups of [`BLOB_ORDER`] store.
const fn stored_len(groups: usize) -> usize {
    let mut len = 0;
    let mut g = 0;
    while g < groups {
        let group = BLOB_ORDER[g];
        let mut i = 0;
        while i < OBJECTS.len() {
            let o = &OBJECTS[i];
            let mut e = 0;
            while e < o.entries.len() {
                if o.entries[e].stored && o.group as u8 == group as u8 {
                    len += group.objects();
                }
                e += 1;
            }
            i += 1;
        }
        g += 1;
    }
    len
}

const fn stored_list() -> [(u16, u8); STORED_LEN] {
    let mut list = [(0, 0); STORED_LEN];
    let mut k = 0;
    let mut g = 0;
    while g < BLOB_ORDER.len() {
        let group = BLOB_ORDER[g];
        let mut pdo = 0;
        while pdo < group.objects() {
            let mut i = 0;
            while i < OBJECTS.len() {
                let o = &OBJECTS[i];
                if o.group as u8 == group as u8 {
                    // Below 0x200 PDOs per range, so the offset fits.
                    let index = o.first + pdo as u16;
                    let mut e = 0;
                    while e < o.entries.len() {
                        if o.entries[e].stored {
                            list[k] = (index, o.entries[e].sub);
                            k += 1;
                        }
                        e += 1;
                    }
                }
                i += 1;
            }
            pdo += 1;
        }
        g += 1;
    }
    list
}

/// Whether a row has behaviour: a parameter among its entries (the table answers
/// constants).
const fn has_parameter(o: &CommObject) -> bool {
    let mut e = 0;
    while e < o.entries.len() {
        if !matches!(o.entries[e].kind, Kind::Constant) {
            return true;
        }
        e += 1;
    }
    false
}

/// How many rows have behaviour.
const ROUTED: usize = {
    let mut n = 0;
    let mut i = 0;
    while i < OBJECTS.len() {
        n += has_parameter(&OBJECTS[i]) as usize;
        i += 1;
    }
    n
};

/// A row of [`OBJECTS`] as the engine uses it at run time.
#[derive(Clone, Copy)]
struct Route {
    first: u16,
    last: u16,
    read: Read,
    write: Write,
    restore: Restore,
}

/// The rows of [`OBJECTS`] with behaviour, without what only the compiler needs (their
/// entries): what the engine looks up at run time.
static ROUTES: [Route; ROUTED] = routes();

const fn routes() -> [Route; ROUTED] {
    let mut routes = [Route {
        first: 0,
        last: 0,
        read: constants_only,
        write: read_only,
        restore: not_a_parameter,
    }; ROUTED];
    let mut k = 0;
    let mut i = 0;
    while i < OBJECTS.len() {
        let o = &OBJECTS[i];
        if has_parameter(o) {
            routes[k] = Route {
                first: o.first,
                last: o.last,
                read: o.read,
                write: o.write,
                restore: o.restore,
            };
            k += 1;
        }
        i += 1;
    }
    routes
}

/// The row of object `index`, if the engine owns it.
fn object(index: u16) -> Option<&'static Route> {
    // One unsigned comparison per row: `first <= index <= last`.
    ROUTES
        .iter()
        .find(|o| index.wrapping_sub(o.first) <= o.last.wrapping_sub(o.first))
}

/// The objects whose COB-IDs must differ (see [`Comm::check_cob_id`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum CobSlot {
    Sync,
    Emcy,
    /// TPDO `n` (0-based).
    Tpdo(usize),
    /// RPDO `n` (0-based).
    Rpdo(usize),
    /// 0x1201 sub-index `n + 1`: 0 client to server, 1 server to client.
    Sdo(usize),
}

impl CobSlot {
    const fn index(self) -> usize {
        match self {
            Self::Sync => 0,
            Self::Emcy => 1,
            Self::Tpdo(n) => 2 + n,
            Self::Rpdo(n) => 2 + TPDOS + n,
            Self::Sdo(n) => 2 + TPDOS + RPDOS + n,
        }
    }
}

impl Comm {
    /// Reads an engine-owned object.
    pub(super) fn read(&self, index: u16, sub: u8) -> Result<u32, SdoAbort> {
        let o = object(index).ok_or(SdoAbort::NoObject)?;
        (o.read)(self, index, sub)
    }

    /// Checked write of an engine-owned object (type and range already checked).
    fn write(
        &mut self,
        ctx: &mut WriteCtx<'_>,
        index: u16,
        sub: u8,
        value: u32,
    ) -> Result<(), SdoAbort> {
        let o = object(index).ok_or(SdoAbort::ReadOnly)?;
        (o.write)(self, ctx, index, sub, value)
    }

    /// Unchecked write of a parameter: table defaults and stored values.
    pub(super) fn restore(&mut self, index: u16, sub: u8, value: u32, now: Instant) {
        if let Some(o) = object(index) {
            (o.restore)(self, index, sub, value, now);
        }
    }

    /// Applies the stored communication parameters (`values`, in [`STORED`]'s order) over
    /// the defaults through the checked write path, with the rules of an SDO write (the
    /// entry's type and range, then the object's own checks): what a master could not have
    /// written is not used. Object by object in the order a master configures them (the
    /// guarded COB-IDs given up first and set last, those at their defaults before changed
    /// ones; a mapping's entries before its count); an object with a refused value keeps its
    /// default (a COB-ID whose default clashes with a restored one stays invalid). Returns
    /// the first refusal and how many objects had one.
    pub(super) fn restore_stored(
        &mut self,
        ctx: &mut WriteCtx<'_>,
        values: &[u32; STORED_LEN],
    ) -> Option<(Refused, u8)> {
        let mut first = None;
        let mut count = 0u8;
        let mut refuse = |r: Refused| {
            warn!(
                "stored {=u16:#06x}:{=u8} not restored ({}): default kept",
                r.index, r.sub, r.abort
            );
            first = first.or(Some(r));
            count = count.saturating_add(1);
        };
        for &(index, sub) in STORED.iter().filter(|&&(i, s)| guarded_cob_id(i, s)) {
            let given_up = self.read(index, sub).unwrap_or(COB_INVALID) | COB_INVALID;
            self.restore(index, sub, given_up, ctx.now);
        }
        let mut k = 0;
        while let Some(&(index, _)) = STORED.get(k) {
            let end = k + STORED[k..].iter().take_while(|e| e.0 == index).count();
            let entries = STORED[k..end].iter().zip(&values[k..end]);
            if let Err(r) = self.restore_object(ctx, index, entries) {
                self.default_object(index, ctx.now);
                refuse(r);
            }
            k = end;
        }
        // The identifiers at their defaults first: of two that clash, the changed one is
        // refused.
        for at_default in [true, false] {
            for (&(index, sub), &value) in STORED.iter().zip(values) {
                // Bit 30 (a TPDO's "no RTR") is not part of the identifier.
                let same = |default: u32| (default ^ value) & !crate::tpdo::NO_RTR == 0;
                let unchanged = self.default_value(index, sub).is_some_and(same);
                if !guarded_cob_id(index, sub) || unchanged != at_default {
                    continue;
                }
                if let Err(abort) = self.write_stored(ctx, index, sub, value) {
                    refuse(Refused { index, sub, abort });
                    let default = self.default_value(index, sub).unwrap_or(COB_INVALID);
                    // Refused as well (it clashes with a restored identifier): stays invalid.
                    let _ = self.write_stored(ctx, index, sub, default);
                }
            }
        }
        first.map(|r| (r, count))
    }

    /// The table default of `(index, sub)` (with the node-ID added where the table says so).
    pub(super) fn default_value(&self, index: u16, sub: u8) -> Option<u32> {
        let node = u32::from(self.node.map_or(0, NodeId::get));
        match self.od.find(index, sub).ok()?.value() {
            Value::Comm(v) => Some(v),
            Value::CommPlusNodeId(v) => Some(v.wrapping_add(node)),
            _ => None,
        }
    }

    /// Object `index` back to its table defaults, but for its guarded COB-ID, which stays
    /// given up until the identifiers are set.
    fn default_object(&mut self, index: u16, now: Instant) {
        let od = self.od;
        for e in od.entries() {
            if e.index() == index && !guarded_cob_id(index, e.sub()) {
                if let Some(value) = self.default_value(index, e.sub()) {
                    self.restore(index, e.sub(), value, now);
                }
            }
        }
    }

    /// The stored sub-indices of one object (the guarded COB-ID left out); a mapping's count
    /// (sub 0) is zeroed first and written last.
    fn restore_object<'a>(
        &mut self,
        ctx: &mut WriteCtx<'_>,
        index: u16,
        entries: impl Iterator<Item = (&'a (u16, u8), &'a u32)> + Clone,
    ) -> Result<(), Refused> {
        let mapping = mapping_object(index);
        let mut write = |c: &mut Self, sub: u8, value: u32| {
            c.write_stored(ctx, index, sub, value)
                .map_err(|abort| Refused { index, sub, abort })
        };
        if mapping {
            write(self, 0, 0)?;
        }
        for (&(_, sub), &value) in entries.clone() {
            let later = guarded_cob_id(index, sub) || (mapping && sub == 0);
            if !later {
                write(self, sub, value)?;
            }
        }
        if let (true, Some((_, &count))) = (mapping, entries.clone().find(|e| e.0 .1 == 0)) {
            write(self, 0, count)?;
        }
        Ok(())
    }

    /// A stored value through the SDO write path: as the entry's type (a value wider than
    /// it is refused), its range, then the object's checks.
    fn write_stored(
        &mut self,
        ctx: &mut WriteCtx<'_>,
        index: u16,
        sub: u8,
        value: u32,
    ) -> Result<(), SdoAbort> {
        let size = self.od.find(index, sub)?.data_type().size().unwrap_or(4);
        let bytes = value.to_le_bytes();
        let (data, rest) = bytes.split_at(size.min(4));
        if rest.iter().any(|&b| b != 0) {
            return Err(SdoAbort::ValueTooHigh);
        }
        self.write_object(ctx.now, index, sub, data, &mut *ctx.app, &mut *ctx.storage)
    }

    /// Communication parameters back to the table's defaults (reset communication).
    pub(super) fn load_defaults(&mut self, now: Instant) {
        // Objects missing from the table stay disabled rather than keeping stale values.
        self.heartbeat = Heartbeat::new();
        self.sync = SyncConsumer::new();
        self.rpdos = [const { Rpdo::new() }; RPDOS];
        self.tpdos = [const { Tpdo::new() }; TPDOS];
        self.emcy.set(0x1014, COB_INVALID);
        self.emcy.set(0x1015, 0);
        self.sdo2 = SDO2_DEFAULTS;
        let node = u32::from(self.node.map_or(0, NodeId::get));
        for e in self.od.entries() {
            match e.value() {
                Value::Comm(v) => self.restore(e.index(), e.sub(), v, now),
                Value::CommPlusNodeId(v) => {
                    self.restore(e.index(), e.sub(), v.wrapping_add(node), now)
                }
                _ => {}
            }
        }
    }

    /// Checks a write of the COB-ID in `slot`: first the object's own rules (format,
    /// restricted identifiers, no change of CAN-ID while valid: 0x06090030), then that no
    /// other object of this node uses it (0x06040043), so that no frame of ours goes out
    /// where the network expects another kind (feed records read as emergencies, a TPDO
    /// taken for SYNC, an SDO request of the second server taken for SYNC or answered as
    /// a PDO, an RPDO taken for SYNC). An entry with bit 31 set claims nothing, except SYNC, which is always
    /// received (bit 31 means nothing to a consumer).
    fn check_cob_id(&self, slot: CobSlot, value: u32) -> Result<(), SdoAbort> {
        let [sdo_rx, sdo_tx, _] = self.sdo2;
        let mut owners = [0; 4 + TPDOS + RPDOS];
        owners[CobSlot::Sync.index()] = self.sync.cob_id() & !COB_INVALID;
        owners[CobSlot::Emcy.index()] = self.emcy.cob_id();
        for (n, t) in self.tpdos.iter().enumerate() {
            if let Some(owner) = owners.get_mut(CobSlot::Tpdo(n).index()) {
                *owner = t.cob_id();
            }
        }
        for (n, r) in self.rpdos.iter().enumerate() {
            if let Some(owner) = owners.get_mut(CobSlot::Rpdo(n).index()) {
                *owner = r.cob_id();
            }
        }
        owners[CobSlot::Sdo(0).index()] = sdo_rx;
        owners[CobSlot::Sdo(1).index()] = sdo_tx;
        let slot = slot.index();
        let value = if slot == CobSlot::Sync.index() {
            SyncConsumer::check(value)?;
            value & !COB_INVALID
        } else {
            check_cob_id_write(owners.get(slot).copied().unwrap_or(0), value)?;
            value
        };
        let clash = value & COB_INVALID == 0
            && owners.iter().enumerate().any(|(other, &raw)| {
                other != slot && raw & COB_INVALID == 0 && (raw ^ value) & 0x7FF == 0
            });
        if clash {
            return Err(SdoAbort::ParameterIncompatible);
        }
        Ok(())
    }

    /// Sets 0x1201 sub-index `sub` (1..=3), unchecked.
    fn set_sdo2(&mut self, sub: u8, value: u32) {
        if let Some(p) = self.sdo2.get_mut(usize::from(sub).wrapping_sub(1)) {
            *p = value;
        }
    }

    /// The (request, reply) identifiers of SDO server `channel`: 0 the default one
    /// (0x600 / 0x580 + node-ID), 1 the one of 0x1201 while both its COB-IDs are valid.
    pub(super) fn sdo_ids(&self, channel: usize) -> Option<(u16, u16)> {
        let node = self.node?;
        let [rx, tx, _] = self.sdo2;
        match channel {
            0 => Some((node.cob_id(cob::SDO_RX), node.cob_id(cob::SDO_TX))),
            // Checked to be 11-bit identifiers: the casts are exact.
            _ => ((rx | tx) & COB_INVALID == 0).then_some((
                (rx & u32::from(MAX_STANDARD_ID)) as u16,
                (tx & u32::from(MAX_STANDARD_ID)) as u16,
            )),
        }
    }

    fn rpdo(&self, n: u16) -> Result<&Rpdo, SdoAbort> {
        self.rpdos.get(usize::from(n)).ok_or(SdoAbort::NoObject)
    }

    fn rpdo_mut(&mut self, n: u16) -> Result<&mut Rpdo, SdoAbort> {
        self.rpdos.get_mut(usize::from(n)).ok_or(SdoAbort::NoObject)
    }

    fn tpdo(&self, n: u16) -> Result<&Tpdo, SdoAbort> {
        self.tpdos.get(usize::from(n)).ok_or(SdoAbort::NoObject)
    }

    fn tpdo_mut(&mut self, n: u16) -> Result<&mut Tpdo, SdoAbort> {
        self.tpdos.get_mut(usize::from(n)).ok_or(SdoAbort::NoObject)
    }

    /// Reads an entry's value into `buf` (no access check: PDOs and uploads check first).
    /// `tpdo`: the PDO (1-based) being built, whose application values may be held ones
    /// ([`Application::read_for_tpdo`]); `None` for an SDO upload.
    pub(super) fn read_value(
        &self,
        e: &OdEntry,
        buf: &mut [u8],
        app: &mut dyn Application,
        tpdo: Option<u8>,
    ) -> Result<usize, SdoAbort> {
        let size = e.data_type().size();
        let raw = match e.value() {
            Value::Const(v) => v,
            Value::Comm(_) | Value::CommPlusNodeId(_) => self.read(e.index(), e.sub())?,
            Value::Str(s) => {
                let dst = buf.get_mut(..s.len()).ok_or(SdoAbort::OutOfMemory)?;
                dst.copy_from_slice(s.as_bytes());
                return Ok(s.len());
            }
            Value::App => {
                let n = match tpdo {
                    Some(pdo) => app.read_for_tpdo(pdo, e.index(), e.sub(), buf)?,
                    None => app.read(e.index(), e.sub(), buf)?,
                };
                // A wrong length is a bug in the application; never pass it on.
                if n > buf.len() || size.is_some_and(|s| s != n) {
                    return Err(SdoAbort::InternalIncompatible);
                }
                return Ok(n);
            }
        };
        // Od::new guarantees that constants and parameters are numeric.
        let n = size.unwrap_or(4);
        let bytes = raw.to_le_bytes();
        let dst = buf.get_mut(..n).ok_or(SdoAbort::OutOfMemory)?;
        dst.copy_from_slice(bytes.get(..n).ok_or(SdoAbort::InternalIncompatible)?);
        Ok(n)
    }

    /// The checked write path shared by SDO and local writes; changes nothing on failure.
    pub(super) fn write_object(
        &mut self,
        now: Instant,
        index: u16,
        sub: u8,
        data: &[u8],
        app: &mut dyn Application,
        storage: &mut dyn Storage,
    ) -> Result<(), SdoAbort> {
        let e = self.od.find(index, sub)?;
        if !e.access().writable() {
            return Err(SdoAbort::ReadOnly);
        }
        let value = e.check_write(data)?;
        match e.value() {
            Value::App => app.write(index, sub, data),
            Value::Comm(_) | Value::CommPlusNodeId(_) => {
                let mut ctx = WriteCtx { now, app, storage };
                self.write(&mut ctx, index, sub, value)
            }
            Value::Const(_) | Value::Str(_) => Err(SdoAbort::ReadOnly),
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::string::ToString;

    #[test]
    fn a_pdo_object_is_named_with_its_pdo_number() {
        let name = |index| comm_object(index).map(|o| o.name(index).to_string());
        assert_eq!(
            name(0x1800).as_deref(),
            Some("TPDO1 communication parameter")
        );
        assert_eq!(name(0x1A01).as_deref(), Some("TPDO2 mapping parameter"));
        assert_eq!(
            name(0x1400).as_deref(),
            Some("RPDO1 communication parameter")
        );
        assert_eq!(name(0x1600).as_deref(), Some("RPDO1 mapping parameter"));
        assert_eq!(name(0x1017).as_deref(), Some("Producer heartbeat time"));
        assert_eq!(name(0x1002), None);
        let mapped = comm_object(0x1A01).and_then(|o| o.entry(3));
        assert_eq!(
            mapped.map(|e| (e.name(), e.is_hex())),
            Some(("Mapped object 3", true))
        );
    }
}
