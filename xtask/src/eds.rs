//! `cargo xtask eds [--check]`: writes `eds/handwheel.eds` (CiA 306) from the device's object
//! table, or (`--check`) fails when the committed file differs from what the table gives.
//!
//! The table is `handwheel_device::od`, built for the host: the run-time dictionary ([`OD`]:
//! type, access, limits, PDO mapping, defaults) and the rows it is made from, which name
//! each object and say what it is: the engine's rows of the communication objects
//! ([`comm_object`]: CiA 301 names, object codes, which values are identifiers, the limits
//! of their own write checks) and the application's ([`APP_OBJECTS`]: names and defaults).
//! `crates/handwheel-device/tests/eds.rs` checks the result against a running device (every
//! default an SDO upload answers, every limit enforced).

use std::fmt::Write as _;
use std::path::Path;
use xshell::cmd;

use canopen_slave::{comm_object, Access, DataType, ObjectCode, OdEntry, Value};
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
    let node = handwheel_storage::record::NodeSettings::DEFAULT
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
NrOfRXPDO={}
NrOfTXPDO={}
LSS_Supported=1

[DummyUsage]
",
        COMM_DEFAULTS.rpdo.len(),
        COMM_DEFAULTS.tpdo.len()
    );
    for dummy in 1..=7u16 {
        let used = u8::from(canopen_slave::rpdo::dummy_size(dummy).is_some());
        let _ = writeln!(out, "Dummy{dummy:04X}={used}");
    }
    out.push_str("\n[Comments]\nLines=0\n");
}

/// Every index of the dictionary, in order.
fn indices() -> Vec<u16> {
    let mut indices: Vec<u16> = OD.entries().map(OdEntry::index).collect();
    indices.dedup();
    indices
}

/// What the rows say of one object beyond its entries: its name and object code, and each
/// sub-index's name, notation and the limits of its write check.
struct Described {
    name: String,
    code: ObjectCode,
    subs: Vec<SubDescribed>,
}

struct SubDescribed {
    sub: u8,
    name: String,
    hex: bool,
    limits: Option<(i64, i64)>,
}

/// Object `index` as its row describes it: the engine's row for a communication object, the
/// application's rows (a record's header row, then one per sub-index) for the others.
fn described(index: u16) -> Result<Described, String> {
    if let Some(o) = comm_object(index) {
        let subs = OD
            .entries()
            .filter(|e| e.index() == index)
            .map(|e| {
                let row = o
                    .entry(e.sub())
                    .ok_or_else(|| format!("{index:04X}sub{:X}: no entry in its row", e.sub()))?;
                Ok(SubDescribed {
                    sub: e.sub(),
                    name: row.name().into(),
                    hex: row.is_hex(),
                    limits: row.write_limits(),
                })
            })
            .collect::<Result<_, String>>()?;
        return Ok(Described {
            name: o.name(index).to_string(),
            code: o.code(),
            subs,
        });
    }
    let rows: Vec<_> = APP_OBJECTS.iter().filter(|o| o.index == index).collect();
    let first = rows
        .first()
        .ok_or_else(|| format!("{index:04X}: no row in the engine's objects or APP_OBJECTS"))?;
    let subs = rows
        .iter()
        .map(|o| SubDescribed {
            sub: o.sub,
            name: if o.is_header() {
                "Highest sub-index supported".into()
            } else {
                o.name.into()
            },
            hex: false,
            limits: None,
        })
        .collect();
    Ok(Described {
        name: first.name.into(),
        code: match (first.is_header(), first.array) {
            (true, true) => ObjectCode::Array,
            (true, false) => ObjectCode::Record,
            (false, _) => ObjectCode::Var,
        },
        subs,
    })
}

/// The section(s) of one object: a VAR, or an ARRAY / RECORD header and its sub-indices.
fn object(out: &mut String, index: u16) -> Result<(), String> {
    out.push('\n');
    if let Some((_, note)) = EDS_NOTES.iter().find(|(i, _)| *i == index) {
        for line in note.lines() {
            let _ = writeln!(out, "; {line}");
        }
    }
    let object = described(index)?;
    if object.code == ObjectCode::Var {
        return match &object.subs[..] {
            [only] if only.sub == 0 => variable(out, &format!("{index:04X}"), index, only),
            _ => Err(format!("{index:04X}: a VAR is one sub-index 0")),
        };
    }
    let _ = write!(
        out,
        "[{index:04X}]\nParameterName={}\nObjectType=0x{:X}\nSubNumber={}\n",
        object.name,
        object.code as u8,
        object.subs.len()
    );
    for sub in &object.subs {
        out.push('\n');
        variable(out, &format!("{index:04X}sub{:X}", sub.sub), index, sub)?;
    }
    Ok(())
}

fn variable(out: &mut String, section: &str, index: u16, d: &SubDescribed) -> Result<(), String> {
    let e = OD
        .find(index, d.sub)
        .map_err(|_| format!("{section}: not in the dictionary"))?;
    let _ = write!(
        out,
        "[{section}]\nParameterName={}\nObjectType=0x7\nDataType=0x{:04X}\nAccessType={}\n",
        d.name,
        eds_type(e.data_type()),
        match e.access() {
            Access::Ro => "ro",
            Access::Wo => "wo",
            Access::Rw => "rw",
            Access::Const => "const",
        }
    );
    if let Some((low, high)) = e.limits().or(d.limits) {
        let _ = write!(out, "LowLimit={low}\nHighLimit={high}\n");
    }
    let _ = write!(
        out,
        "DefaultValue={}\nPDOMapping={}\n",
        default(e, d.hex)?,
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

/// The value a fresh device reports (the table's default), as the EDS writes it: in hex
/// where the row says so, COB-IDs relative to the node-ID as `$NODEID+`, the rest in decimal.
fn default(e: &OdEntry, hex: bool) -> Result<String, String> {
    let (index, sub) = (e.index(), e.sub());
    Ok(match e.value() {
        Value::Str(s) => s.to_string(),
        Value::Const(v) | Value::Comm(v) if hex => format!("0x{v:08X}"),
        Value::Const(v) | Value::Comm(v) => v.to_string(),
        Value::CommPlusNodeId(v) => format!("$NODEID+0x{v:X}"),
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
        let rows: Vec<_> = APP_OBJECTS.iter().filter(|o| !o.is_header()).collect();
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
