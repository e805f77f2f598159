//! `cargo xtask eds [--check]`: writes `eds/handwheel.eds` (CiA 306) from the device's object
//! table, or (`--check`) fails when the committed file differs from what the table gives.
//!
//! The table is `handwheel_device::od`, built for the host: the run-time dictionary ([`OD`]:
//! type, access, limits, PDO mapping, where each value lives) and the application objects'
//! rows ([`APP_OBJECTS`]: names and defaults). What the run-time table does not carry for the
//! communication objects, their CiA 301 names and object types and the values the engine
//! reports for them, is in [`comm_name`] and [`comm_default`]: the engine's knowledge,
//! which `crates/handwheel-device/tests/eds.rs` checks against a running device (every
//! default an SDO upload answers, every limit enforced).

use std::fmt::Write as _;
use std::path::Path;
use xshell::cmd;

use canopen_slave::tpdo::{MAX_MAPPED, NO_RTR};
use canopen_slave::{Access, DataType, OdEntry, Value};
use handwheel_core::BitRate;
use handwheel_device::od::{APP_OBJECTS, COMM_DEFAULTS, EDS_NOTES, IDENTITY, OD};

/// The file, relative to the workspace root.
pub const PATH: &str = "eds/handwheel.eds";

/// `cargo xtask eds [--check]`: then [`dcfchk`] on the file.
pub fn run(root: &Path, target_dir: &Path, args: &[String]) -> Result<(), String> {
    let check = match args {
        [] => false,
        [flag] if flag == "--check" => true,
        _ => return Err("usage: cargo xtask eds [--check]".into()),
    };
    let path = root.join(PATH);
    let text = generate()?;
    if check {
        let committed = std::fs::read(&path).map_err(|e| format!("{PATH}: {e}"))?;
        if committed != text.as_bytes() {
            return Err(format!(
                "{PATH} differs from the object table: run `cargo xtask eds` and commit it"
            ));
        }
        println!("xtask: {PATH} is the object table's");
    } else {
        std::fs::write(&path, text).map_err(|e| format!("{PATH}: {e}"))?;
        println!("xtask: wrote {PATH}");
    }
    dcfchk(root, target_dir)
}

/// Lely's CiA 306 checker `dcfchk` (PyPI `dcf-tools`, pinned in the documents' venv,
/// `tools/wiring/requirements.txt`) on the file, for the device's default node-ID: an
/// independent reading of the EDS, as a master's tool would read it.
fn dcfchk(root: &Path, target_dir: &Path) -> Result<(), String> {
    let python = crate::wiring::python(root, target_dir)?;
    let dcfchk = python.with_file_name("dcfchk");
    let node = handwheel_device::record::NodeSettings::DEFAULT
        .node_id
        .map_or(0, canopen_slave::NodeId::get)
        .to_string();
    let sh = crate::shell::at(root)?;
    crate::shell::run(cmd!(sh, "{dcfchk} -n {node} {PATH}"))
        .map_err(|e| format!("dcfchk refused {PATH}: {e}"))
}

/// Which indices one of the EDS's object lists holds.
type IndexFilter = fn(u16) -> bool;

/// The EDS, with the CRLF line ends CiA 306 tools expect.
pub fn generate() -> Result<String, String> {
    let mut out = String::new();
    header(&mut out);
    let indices = indices();
    let lists: [(&str, IndexFilter); 3] = [
        ("MandatoryObjects", |i| {
            matches!(i, 0x1000 | 0x1001 | 0x1018)
        }),
        ("OptionalObjects", |i| {
            !matches!(i, 0x1000 | 0x1001 | 0x1018 | 0x2000..=0x5FFF)
        }),
        ("ManufacturerObjects", |i| (0x2000..=0x5FFF).contains(&i)),
    ];
    for (name, member) in lists {
        let listed: Vec<u16> = indices.iter().copied().filter(|&i| member(i)).collect();
        let _ = write!(out, "\n[{name}]\nSupportedObjects={}\n", listed.len());
        for (n, index) in listed.iter().enumerate() {
            let _ = writeln!(out, "{}=0x{index:04X}", n + 1);
        }
    }
    for index in indices {
        object(&mut out, index)?;
    }
    Ok(out.replace('\n', "\r\n"))
}

fn header(out: &mut String) {
    let id = &IDENTITY;
    let _ = write!(
        out,
        "; Electronic data sheet (CiA 306) of the CANopen CNC handwheel.
; Written by `cargo xtask eds` from the device's object table (crates/handwheel-device):
; change the table, not this file.
[FileInfo]
FileName=handwheel.eds
FileVersion=1
FileRevision=1
EDSVersion=4.0
Description=CANopen CNC handwheel (manual pulse generator)
CreationTime=12:00PM
CreationDate=11-22-2026
CreatedBy=handwheel project
ModificationTime=12:00PM
ModificationDate=11-24-2026
ModifiedBy=handwheel project

[DeviceInfo]
VendorName=handwheel project
VendorNumber=0x{:08X}
ProductName={}
ProductNumber=0x{:08X}
RevisionNumber=0x{:08X}
OrderCode=
",
        id.vendor_id, id.device_name, id.product_code, id.revision
    );
    let mut rates = BitRate::ALL.map(BitRate::kbit_per_second);
    rates.sort_unstable();
    for kbit in rates {
        let _ = writeln!(out, "BaudRate_{kbit}=1");
    }
    let _ = write!(
        out,
        "SimpleBootUpMaster=0
SimpleBootUpSlave=1
Granularity=8
DynamicChannelsSupported=0
GroupMessaging=0
NrOfRXPDO=0
NrOfTXPDO={}
LSS_Supported=1

[DummyUsage]
",
        COMM_DEFAULTS.tpdo.len()
    );
    for dummy in 1..=7 {
        let _ = writeln!(out, "Dummy{dummy:04X}=0");
    }
    out.push_str("\n[Comments]\nLines=0\n");
}

/// Every index of the dictionary, in order.
fn indices() -> Vec<u16> {
    let mut indices: Vec<u16> = OD.entries().map(OdEntry::index).collect();
    indices.dedup();
    indices
}

/// The section(s) of one object: a VAR, or an ARRAY / RECORD header and its sub-indices.
fn object(out: &mut String, index: u16) -> Result<(), String> {
    let entries: Vec<&OdEntry> = OD.entries().filter(|e| e.index() == index).collect();
    out.push('\n');
    if let Some((_, note)) = EDS_NOTES.iter().find(|(i, _)| *i == index) {
        for line in note.lines() {
            let _ = writeln!(out, "; {line}");
        }
    }
    let name = name_of(index, None)?;
    if let [single] = entries[..] {
        if single.sub() == 0 && !is_header(single) {
            return variable(out, &format!("{index:04X}"), &name, single);
        }
    }
    // CiA 301 defines these four as arrays (one type for sub-indices 1 and up); every other
    // object with sub-indices here is a record.
    let object_type = if matches!(index, 0x1003 | 0x1010 | 0x1011 | 0x1016) {
        8
    } else {
        9
    };
    let _ = write!(
        out,
        "[{index:04X}]\nParameterName={name}\nObjectType=0x{object_type:X}\nSubNumber={}\n",
        entries.len()
    );
    for e in entries {
        out.push('\n');
        let sub_name = name_of(index, Some(e.sub()))?;
        variable(out, &format!("{index:04X}sub{:X}", e.sub()), &sub_name, e)?;
    }
    Ok(())
}

/// Sub-index 0 of a record or array that says its highest sub-index.
fn is_header(e: &OdEntry) -> bool {
    e.sub() == 0 && e.access() == Access::Const && e.data_type() == DataType::U8
}

fn variable(out: &mut String, section: &str, name: &str, e: &OdEntry) -> Result<(), String> {
    let _ = write!(
        out,
        "[{section}]\nParameterName={name}\nObjectType=0x7\nDataType=0x{:04X}\nAccessType={}\n",
        eds_type(e.data_type()),
        match e.access() {
            Access::Ro => "ro",
            Access::Wo => "wo",
            Access::Rw => "rw",
            Access::Const => "const",
        }
    );
    let limits = match (e.index(), e.sub(), e.limits()) {
        (_, _, Some(limits)) => Some(limits),
        // The engine refuses a mapping count above what a PDO holds.
        (0x1A00..=0x1BFF, 0, None) => Some((0, MAX_MAPPED as i64)),
        _ => None,
    };
    if let Some((low, high)) = limits {
        let _ = write!(out, "LowLimit={low}\nHighLimit={high}\n");
    }
    let _ = write!(
        out,
        "DefaultValue={}\nPDOMapping={}\n",
        default(e)?,
        u8::from(e.is_mappable())
    );
    Ok(())
}

fn eds_type(t: DataType) -> u16 {
    match t {
        DataType::Boolean => 0x0001,
        DataType::I8 => 0x0002,
        DataType::I16 => 0x0003,
        DataType::I32 => 0x0004,
        DataType::U8 => 0x0005,
        DataType::U16 => 0x0006,
        DataType::U32 => 0x0007,
        DataType::VisibleString => 0x0009,
    }
}

/// The value a fresh device reports, as the EDS writes it: identifiers and 32-bit constants
/// in hex, counts and times in decimal, COB-IDs with the node-ID as `$NODEID+`.
fn default(e: &OdEntry) -> Result<String, String> {
    let (index, sub) = (e.index(), e.sub());
    let hex = |v: u32| format!("0x{v:08X}");
    Ok(match e.value() {
        Value::Str(s) => s.to_string(),
        Value::Const(v) if e.data_type() == DataType::U32 => hex(v),
        Value::Const(v) => v.to_string(),
        Value::Comm(v) => match comm_default(index, sub, v) {
            v if index == 0x1005 || (matches!(index, 0x1A00..=0x1BFF) && sub > 0) => hex(v),
            v => v.to_string(),
        },
        Value::CommPlusNodeId(v) => format!("$NODEID+0x{:X}", comm_default(index, sub, v)),
        Value::App => {
            let row = APP_OBJECTS
                .iter()
                .find(|o| (o.index, o.sub) == (index, sub))
                .ok_or_else(|| format!("{index:04X}sub{sub}: no row in APP_OBJECTS"))?;
            match e.data_type() {
                DataType::I8 | DataType::I16 | DataType::I32 => (row.default as i32).to_string(),
                _ => row.default.to_string(),
            }
        }
    })
}

/// What the engine reports for a communication parameter whose table default is `table`.
fn comm_default(index: u16, sub: u8, table: u32) -> u32 {
    match (index, sub) {
        // 0x1010 / 0x1011 read their capability: bit 0, on command.
        (0x1010 | 0x1011, 1..) => 1,
        // A TPDO's COB-ID reads with bit 30 set: no RTR on this PDO.
        (0x1800..=0x19FF, 1) => table | NO_RTR,
        _ => table,
    }
}

/// The name of object `index` (`sub` `None`) or of one of its sub-indices.
fn name_of(index: u16, sub: Option<u8>) -> Result<String, String> {
    if index >= 0x2000 {
        let row = APP_OBJECTS
            .iter()
            .find(|o| o.index == index && (Some(o.sub) == sub || (sub.is_none() && o.sub == 0)));
        return match (row, sub) {
            (Some(o), Some(0)) if o.header => Ok("Highest sub-index supported".into()),
            (Some(o), _) => Ok(o.name.into()),
            (None, _) => Err(format!("{index:04X}: no row in APP_OBJECTS")),
        };
    }
    comm_name(index, sub).ok_or_else(|| {
        format!("{index:04X}sub{sub:?}: no CiA 301 name in xtask/src/eds.rs (comm_name)")
    })
}

/// CiA 301's names of the communication objects the engine implements.
fn comm_name(index: u16, sub: Option<u8>) -> Option<String> {
    let pdo = index & 0x1FF;
    let name = match (index, sub) {
        (0x1010 | 0x1011 | 0x1016 | 0x1018 | 0x1800..=0x19FF, Some(0)) => {
            "Highest sub-index supported".into()
        }
        (0x1003, Some(0)) => "Number of errors".into(),
        (0x1A00..=0x1BFF, Some(0)) => "Number of mapped objects".into(),
        (0x1000, _) => "Device type".into(),
        (0x1001, _) => "Error register".into(),
        (0x1003, None) => "Pre-defined error field".into(),
        (0x1003, Some(n)) => format!("Standard error field {n}"),
        (0x1005, _) => "COB-ID SYNC".into(),
        (0x1008, _) => "Manufacturer device name".into(),
        (0x1009, _) => "Manufacturer hardware version".into(),
        (0x100A, _) => "Manufacturer software version".into(),
        (0x1010, None) => "Store parameters".into(),
        (0x1010, Some(1)) => "Save all parameters".into(),
        (0x1010, Some(2)) => "Save communication parameters".into(),
        (0x1010, Some(3)) => "Save application parameters".into(),
        (0x1011, None) => "Restore default parameters".into(),
        (0x1011, Some(1)) => "Restore all default parameters".into(),
        (0x1011, Some(2)) => "Restore communication default parameters".into(),
        (0x1011, Some(3)) => "Restore application default parameters".into(),
        (0x1014, _) => "COB-ID EMCY".into(),
        (0x1015, _) => "Inhibit time EMCY".into(),
        (0x1016, None) => "Consumer heartbeat time".into(),
        (0x1016, Some(n)) => format!("Consumer heartbeat time {n}"),
        (0x1017, _) => "Producer heartbeat time".into(),
        (0x1018, None) => "Identity object".into(),
        (0x1018, Some(1)) => "Vendor-ID".into(),
        (0x1018, Some(2)) => "Product code".into(),
        (0x1018, Some(3)) => "Revision number".into(),
        (0x1018, Some(4)) => "Serial number".into(),
        (0x1800..=0x19FF, None) => format!("TPDO{} communication parameter", pdo + 1),
        (0x1800..=0x19FF, Some(1)) => "COB-ID used by TPDO".into(),
        (0x1800..=0x19FF, Some(2)) => "Transmission type".into(),
        (0x1800..=0x19FF, Some(3)) => "Inhibit time".into(),
        (0x1800..=0x19FF, Some(5)) => "Event timer".into(),
        (0x1A00..=0x1BFF, None) => format!("TPDO{} mapping parameter", pdo + 1),
        (0x1A00..=0x1BFF, Some(n)) => format!("Mapped object {n}"),
        _ => return None,
    };
    Some(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The committed file is the table's (what `cargo xtask eds --check` checks, here also
    /// for a plain `cargo test`).
    #[test]
    fn the_committed_eds_is_generated_from_the_table() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let committed = std::fs::read_to_string(root.join(PATH)).unwrap();
        assert!(
            committed == generate().unwrap(),
            "{PATH} differs from the object table: run `cargo xtask eds`"
        );
    }

    #[test]
    fn every_line_ends_in_crlf() {
        let text = generate().unwrap();
        assert!(text.ends_with("\r\n"));
        assert_eq!(text.matches('\n').count(), text.matches("\r\n").count());
    }

    /// The README's table of the handwheel objects says what the rows say: every row but
    /// the record headers is a line, with its name, type, access, default and PDO mapping.
    #[test]
    fn the_readme_table_is_the_rows() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
        let table = readme
            .split("#### Handwheel objects")
            .nth(1)
            .and_then(|rest| rest.split("\n\n").find(|block| block.starts_with('|')))
            .expect("README has the handwheel objects' table");
        let lines: Vec<Vec<&str>> = table
            .lines()
            .skip(2)
            .map(|line| line.split('|').map(str::trim).collect())
            .collect();
        let rows: Vec<_> = APP_OBJECTS.iter().filter(|o| !o.header).collect();
        assert_eq!(lines.len(), rows.len(), "one README line per object");
        for (cells, o) in lines.iter().zip(rows) {
            let key = if o.sub == 0 {
                format!("0x{:04X}", o.index)
            } else {
                format!("0x{:04X}:{}", o.index, o.sub)
            };
            let [_, index, name, data_type, access, default, pdo, ..] = cells[..] else {
                panic!("{key}: a short README line");
            };
            assert_eq!(index, key);
            assert_eq!(name, o.name.to_lowercase(), "{key} name");
            let type_name = format!("{:?}", o.data_type);
            assert!(data_type.starts_with(&type_name), "{key} type {data_type}");
            let access_name = format!("{:?}", o.access).to_lowercase();
            assert_eq!(access, access_name, "{key} access");
            assert_eq!(default, o.default.to_string(), "{key} default");
            assert_eq!(pdo == "yes", o.mappable, "{key} PDO mapping");
        }
    }
}
