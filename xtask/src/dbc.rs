//! `cargo xtask dbc [--check] | --node N`: the device's transmit PDOs as a CAN database (DBC),
//! for cantools, SavvyCAN, Wireshark and any CAN tool that decodes frames by one.
//! `eds/handwheel.dbc` is the default node-ID's (`--check`: fail when the committed file
//! differs); `--node N` prints the database of node N.
//!
//! Nothing here is a copy of the layout. What it reads, and so what it depends on:
//! - the TPDOs' default COB-ID bases and mappings: [`COMM_DEFAULTS`]`.tpdo` (each mapping
//!   entry `index << 16 | sub << 8 | bits`, in order: the bits a mapped object takes);
//! - each mapped object's name and data type: the rows of [`APP_OBJECTS`] (by index and
//!   sub-index), and the names of the selection record 0x2010's sub-indices and of the
//!   feed session 0x2002 for the fields the feed record packs into one byte;
//! - where those fields lie inside their byte: handwheel-core's own encoders
//!   ([`FeedState::selection_byte`], [`FeedState::status_byte`], [`UnitStepEncoder::peek`]),
//!   probed field by field here, and the flags of [`FeedStatus`];
//! - the default node-ID: [`NodeSettings::DEFAULT`](handwheel_storage::record::NodeSettings).

use std::fmt::Write as _;
use std::path::Path;

use canopen_slave::DataType;
use handwheel_core::{
    Axis, CounterStride, FeedState, FeedStatus, Multiplier, UnitStep, UnitStepEncoder,
};
use handwheel_device::od::{
    APP_OBJECTS, COMM_DEFAULTS, FEED_SELECTION, FEED_SESSION, FEED_STATUS, SELECTION, UNIT_STEP,
};
use handwheel_storage::record::NodeSettings;

/// The file for the default node-ID, relative to the workspace root.
pub const PATH: &str = "eds/handwheel.dbc";

/// `cargo xtask dbc [--check] | --node N`.
pub fn run(root: &Path, args: &[String]) -> Result<(), String> {
    const USAGE: &str = "usage: cargo xtask dbc [--check] | --node N";
    match args {
        [] | [_] if args.iter().all(|a| a == "--check") => {
            let text = generate(default_node())?;
            let path = root.join(PATH);
            if args.is_empty() {
                std::fs::write(&path, text).map_err(|e| format!("{PATH}: {e}"))?;
                println!("xtask: wrote {PATH}");
            } else {
                let committed = std::fs::read(&path).map_err(|e| format!("{PATH}: {e}"))?;
                if committed != text.as_bytes() {
                    return Err(format!(
                        "{PATH} differs from the object table: run `cargo xtask dbc` and commit it"
                    ));
                }
                println!("xtask: {PATH} is the object table's");
            }
            Ok(())
        }
        [flag, node] if flag == "--node" => {
            let node: u8 = node
                .parse()
                .ok()
                .filter(|n| (1..=127).contains(n))
                .ok_or_else(|| format!("--node {node}: node-IDs are 1..127"))?;
            print!("{}", generate(node)?);
            Ok(())
        }
        _ => Err(USAGE.into()),
    }
}

/// The node-ID a fresh device has.
pub fn default_node() -> u8 {
    NodeSettings::DEFAULT
        .node_id
        .map_or(16, canopen_slave::NodeId::get)
}

/// One signal: `bits` bits from `start` (little-endian, as every CANopen PDO).
#[derive(Debug, Clone, PartialEq)]
struct Signal {
    name: String,
    start: u32,
    bits: u32,
    signed: bool,
    comment: String,
    /// Raw value -> name, for fields that are codes.
    values: Vec<(u32, String)>,
}

/// A field inside one mapped byte: its bits (from probing the encoder) and what it is.
struct Field {
    name: String,
    mask: u32,
    comment: String,
    values: Vec<(u32, String)>,
}

/// The DBC of node `node`: one message per default TPDO and RPDO, its mapped objects as
/// signals.
pub fn generate(node: u8) -> Result<String, String> {
    let mut out = String::new();
    let _ = write!(
        out,
        "VERSION \"\"\n\n\
         NS_ :\n\tCM_\n\tVAL_\n\n\
         BS_:\n\n\
         BU_: Handwheel Master\n"
    );
    let mut comments = String::new();
    let mut tables = String::new();
    // The device's TPDOs (sent by the handwheel), then its RPDOs (sent by a master).
    let tpdos = COMM_DEFAULTS.tpdo.iter().enumerate().map(|(n, t)| {
        let name = format!("TPDO{}", n + 1);
        (name, t.cob_id_base, t.mapping, "Handwheel")
    });
    let rpdos = COMM_DEFAULTS.rpdo.iter().enumerate().map(|(n, r)| {
        let name = format!("RPDO{}", n + 1);
        (name, r.cob_id_base, r.mapping, "Master")
    });
    for (name, cob_id_base, mapping, sender) in tpdos.chain(rpdos) {
        let cob_id = cob_id_base + u32::from(node);
        let mut signals = Vec::new();
        let mut offset = 0;
        for &entry in mapping {
            let (index, sub, bits) = ((entry >> 16) as u16, (entry >> 8) as u8, entry & 0xFF);
            signals.extend(signals_of(index, sub, offset, bits)?);
            offset += bits;
        }
        let bytes = offset.div_ceil(8);
        let _ = write!(out, "\nBO_ {cob_id} {name}: {bytes} {sender}\n");
        for s in &signals {
            let (sign, (low, high)) = if s.signed {
                ('-', (-(1i64 << (s.bits - 1)), (1i64 << (s.bits - 1)) - 1))
            } else {
                ('+', (0, (1i64 << s.bits) - 1))
            };
            let receiver = if sender == "Handwheel" {
                "Vector__XXX"
            } else {
                "Handwheel"
            };
            let _ = writeln!(
                out,
                " SG_ {} : {}|{}@1{sign} (1,0) [{low}|{high}] \"\" {receiver}",
                s.name, s.start, s.bits
            );
            let _ = writeln!(comments, "CM_ SG_ {cob_id} {} \"{}\";", s.name, s.comment);
            if !s.values.is_empty() {
                let _ = write!(tables, "VAL_ {cob_id} {}", s.name);
                for (v, label) in &s.values {
                    let _ = write!(tables, " {v} \"{label}\"");
                }
                tables.push_str(" ;\n");
            }
        }
        let mapped: Vec<String> = mapping
            .iter()
            .map(|m| format!("0x{:04X}:{}", m >> 16, (m >> 8) & 0xFF))
            .collect();
        let _ = writeln!(
            comments,
            "CM_ BO_ {cob_id} \"{name} of node {node}, default mapping {}\";",
            mapped.join(", ")
        );
    }
    let _ = write!(
        out,
        "\nCM_ \"The CANopen CNC handwheel's PDOs (its TPDOs, and the RPDOs a master sends it), \
         written by `cargo xtask dbc` from the device's object table: change the table, not \
         this file.\";\n{comments}{tables}"
    );
    Ok(out)
}

/// The signals of mapped object `index:sub` at bit `offset`, `bits` wide: its fields if it
/// packs several into one byte, else the object itself.
fn signals_of(index: u16, sub: u8, offset: u32, bits: u32) -> Result<Vec<Signal>, String> {
    let (name, data_type) = row(index, sub)?;
    let fields = packed_fields(index)?;
    if fields.is_empty() {
        let signed = matches!(data_type, DataType::I8 | DataType::I16 | DataType::I32);
        return Ok(vec![Signal {
            name: camel(name),
            start: offset,
            bits,
            signed,
            comment: format!("0x{index:04X}:{sub} {name}"),
            values: Vec::new(),
        }]);
    }
    let mut signals = Vec::new();
    for f in fields {
        let low = f.mask.trailing_zeros();
        let width = f.mask.count_ones();
        if f.mask >> low != (1 << width) - 1 || low + width > bits {
            return Err(format!(
                "0x{index:04X}: {} is no run of bits (mask {:#x})",
                f.name, f.mask
            ));
        }
        signals.push(Signal {
            name: f.name,
            start: offset + low,
            bits: width,
            signed: false,
            comment: format!(
                "0x{index:04X}:{sub} {name}, {}: {}",
                if width == 1 {
                    format!("bit {low}")
                } else {
                    format!("bits {low}..{}", low + width - 1)
                },
                f.comment
            ),
            values: f.values,
        });
    }
    Ok(signals)
}

/// The name and data type of object `index:sub`.
fn row(index: u16, sub: u8) -> Result<(&'static str, DataType), String> {
    APP_OBJECTS
        .iter()
        .find(|o| (o.index, o.sub) == (index, sub) && !o.is_header())
        .map(|o| (o.name, o.data_type))
        .ok_or_else(|| format!("0x{index:04X}:{sub}: no row in APP_OBJECTS"))
}

/// `Feed selection` -> `FeedSelection`.
fn camel(name: &str) -> String {
    name.split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|w| !w.is_empty())
        .map(|w| {
            let mut c = w.chars();
            c.next()
                .map(|first| first.to_ascii_uppercase().to_string() + c.as_str())
                .unwrap_or_default()
        })
        .collect()
}

/// The bits of `byte` that `vary` sets, over every value it takes.
fn probe(values: impl Iterator<Item = u8>) -> u32 {
    values.fold(0, |mask, v| mask | u32::from(v))
}

/// The fields an object packs into its byte (empty: it is one value).
fn packed_fields(index: u16) -> Result<Vec<Field>, String> {
    let sel = |sub: u8| row(SELECTION, sub).map(|(name, _)| camel(name));
    Ok(match index {
        FEED_SELECTION => {
            let with = |f: &dyn Fn(&mut FeedState)| {
                let mut s = FeedState::ZERO;
                f(&mut s);
                s.selection_byte()
            };
            let mut axes = vec![(0, "none".to_string())];
            axes.extend(
                Axis::ALL
                    .iter()
                    .map(|a| (u32::from(a.object_value()), format!("{a:?}"))),
            );
            let multipliers: Vec<Multiplier> = (0..4).filter_map(Multiplier::from_code).collect();
            vec![
                Field {
                    name: sel(1)?,
                    mask: probe(Axis::ALL.iter().map(|&a| with(&|s| s.axis = Some(a)))),
                    comment: "the switch position, 0 none".into(),
                    values: axes,
                },
                Field {
                    name: sel(2)?,
                    mask: probe(multipliers.iter().map(|&m| with(&|s| s.multiplier = m))),
                    comment: "the multiplier's code".into(),
                    values: multipliers
                        .iter()
                        .map(|m| (u32::from(m.code()), format!("x{}", m.factor())))
                        .collect(),
                },
                Field {
                    name: sel(3)?,
                    mask: probe((0..8).map(|e| with(&|s| s.epoch = e))),
                    comment: "the low three bits of the selection epoch".into(),
                    values: Vec::new(),
                },
            ]
        }
        FEED_STATUS => {
            let with = |f: &dyn Fn(&mut FeedState)| {
                let mut s = FeedState::ZERO;
                f(&mut s);
                s.status_byte()
            };
            let flags = [
                (
                    "FeedEnabled",
                    FeedStatus::ENABLED,
                    "0x2000 = 1 and not stopped since",
                ),
                (
                    "EncoderError",
                    FeedStatus::ENCODER_ERROR,
                    "an illegal quadrature transition in this epoch",
                ),
                (
                    "StepsDropped",
                    FeedStatus::STEPS_DROPPED,
                    "unit steps dropped in this epoch",
                ),
                (
                    "MasterLost",
                    FeedStatus::MASTER_LOST,
                    "the feed stopped by a loss of communication",
                ),
                (
                    "IgnoredMotion",
                    FeedStatus::IGNORED_MOTION,
                    "turned while disabled or without an axis in this epoch",
                ),
            ];
            let mut fields: Vec<Field> = flags
                .iter()
                .map(|&(name, flag, comment)| Field {
                    name: name.into(),
                    mask: u32::from(with(&|s| s.status = flag)),
                    comment: comment.into(),
                    values: Vec::new(),
                })
                .collect();
            fields.push(Field {
                name: camel(row(FEED_SESSION, 0)?.0),
                mask: probe((0..8).map(|n| with(&|s| s.session = n))),
                comment: "the session (0x2002) the record belongs to, 0 none".into(),
                values: Vec::new(),
            });
            fields
        }
        UNIT_STEP => {
            let peek =
                |encoder: &UnitStepEncoder, axis, forward| encoder.peek(UnitStep { axis, forward });
            let fresh = UnitStepEncoder::new(CounterStride::One);
            let mut counted = fresh;
            let mut counters = 0;
            for _ in 0..16 {
                counters |= u32::from(peek(&counted, Axis::X, false));
                counted.advance();
            }
            vec![
                Field {
                    name: "UnitStepAxis".into(),
                    mask: probe(Axis::ALL.iter().map(|&a| peek(&fresh, a, false))),
                    comment: "the axis, X = 0 .. V = 4".into(),
                    values: Axis::ALL
                        .iter()
                        .map(|a| (u32::from(a.paper_index()), format!("{a:?}")))
                        .collect(),
                },
                Field {
                    name: "UnitStepForward".into(),
                    mask: u32::from(peek(&fresh, Axis::X, true)),
                    comment: "1 forward, 0 backward".into(),
                    values: Vec::new(),
                },
                Field {
                    name: "UnitStepCounter".into(),
                    mask: counters,
                    comment: "+1 per frame".into(),
                    values: Vec::new(),
                },
            ]
        }
        _ => Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The committed file is the table's (what `cargo xtask dbc --check` checks, here also
    /// for a plain `cargo test`).
    #[test]
    fn the_committed_dbc_is_generated_from_the_table() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let committed = std::fs::read_to_string(root.join(PATH)).unwrap();
        assert!(
            committed == generate(default_node()).unwrap(),
            "{PATH} differs from the object table: run `cargo xtask dbc`"
        );
    }

    /// The feed record's signals cover its 64 bits once each, where README "Feed record"
    /// puts them.
    #[test]
    fn the_feed_record_signals_tile_its_bytes() {
        let mut signals = Vec::new();
        let mut offset = 0;
        for &entry in COMM_DEFAULTS.tpdo[0].mapping {
            let (index, sub, bits) = ((entry >> 16) as u16, (entry >> 8) as u8, entry & 0xFF);
            signals.extend(signals_of(index, sub, offset, bits).unwrap());
            offset += bits;
        }
        let layout: Vec<(&str, u32, u32, bool)> = signals
            .iter()
            .map(|s| (s.name.as_str(), s.start, s.bits, s.signed))
            .collect();
        assert_eq!(
            layout,
            [
                ("PositionValue", 0, 32, true),
                ("Axis", 32, 3, false),
                ("Multiplier", 35, 2, false),
                ("SelectionEpoch", 37, 3, false),
                ("FeedEnabled", 40, 1, false),
                ("EncoderError", 41, 1, false),
                ("StepsDropped", 42, 1, false),
                ("MasterLost", 43, 1, false),
                ("IgnoredMotion", 44, 1, false),
                ("FeedSession", 45, 3, false),
                ("FeedSequence", 48, 16, false),
            ]
        );
    }

    #[test]
    fn another_node_moves_only_the_identifiers() {
        let five = generate(5).unwrap();
        assert!(five.contains("BO_ 389 TPDO1: 8 Handwheel"));
        assert!(five.contains("BO_ 645 TPDO2: 1 Handwheel"));
        assert!(five.contains("BO_ 517 RPDO1: 1 Master"));
        assert!(five.contains("VAL_ 389 Multiplier 0 \"x1\" 1 \"x10\" 2 \"x100\" ;"));
        let default = generate(default_node()).unwrap();
        assert_eq!(
            five.replace("389", "400")
                .replace("645", "656")
                .replace("517", "528")
                .replace("node 5", "node 16"),
            default
        );
    }
}
