//! `cargo xtask contract [--check]`: the update contract of docs/FIRMWARE-UPDATE.md, as the
//! loader's crate states it, written for the Python that speaks it: the memory map
//! (`canopen_loader::layout`, which a test holds to `memory.x`), the image header (mark,
//! format, length, fields' offsets: `header`), the hand-off words (`layout`, `boot`), the
//! loader's identity (`node`) and its 0x1F57 codes with their meanings (`program`). [`PATH`]
//! is the one Python module that holds them (standard library only, no imports); the host
//! command (`image.py`, `update.py`), the seal (`tools/seal`) and the rig's broken images
//! import it (`--check`: fail when the committed file differs).
//!
//! Nothing here is a value of the contract: every number and text is the crate's; this file
//! only names and comments them for Python.

use std::fmt::Write as _;
use std::path::Path;

use canopen_loader::boot::{LISTEN_MS, MAX_TRIAL_STARTS, TRIAL_TAG};
use canopen_loader::header::{
    CRC_AT, FIELDS, FORMAT, FORMAT_AT, HEADER_LEN, HEADER_SIZE_AT, LENGTH_AT, MAGIC, MAGIC_AT,
    MIN_IMAGE, PRODUCT_CODE_AT, RESERVED_AT, UNSET, VENDOR_ID_AT, VERSION_AT,
};
use canopen_loader::layout::{
    APP_ORIGIN, CHIP_FLASH_SIZE, HANDOFF_LENGTH, HANDOFF_ORIGIN, HANDOFF_REQUEST, HEADER_SLOT,
    LOADER_LENGTH, LOADER_ORIGIN, MAX_IMAGE, PAGE_SIZE, RAM_LENGTH, RAM_ORIGIN, SLOT_ORIGIN,
    SLOT_PAGES, SLOT_SIZE, STORAGE_LENGTH, STORAGE_ORIGIN,
};
use canopen_loader::node::{DEVICE_TYPE, LOADER_PRODUCT_BIT};
use canopen_loader::program::{FlashStatus, FLASH_CODE_MASK, FLASH_CODE_SHIFT, FLASH_IN_PROGRESS};

/// The module, relative to the workspace root.
pub const PATH: &str = "host/src/canopen_handwheel/update_contract.py";

/// Ruff's line length (ruff.toml): the generated module passes `ruff format --check` as is.
const LINE: usize = 100;

/// The module's head: the mark that it is generated, and its docstring.
const PREAMBLE: &str = r#"# written by `cargo xtask contract` from crates/canopen-loader: change the Rust, not this file
"""The update contract of docs/FIRMWARE-UPDATE.md as the loader's crate states it
(crates/canopen-loader): the memory map (`layout`, which a test holds to memory.x), the image
header (`header`), the hand-off words between loader and application (`layout`, `boot`), the
loader's identity (`node`) and its 0x1F57 flash status codes with their meanings (`program`).
`cargo xtask contract --check`, part of `cargo xtask test`, fails when this file is not the
crate's.

Constants only, no imports: the host command (image.py, update.py), the seal (tools/seal, run
at every firmware link by any python3) and the rig's broken images (tools/rig/bad_images.py)
import it.
"""

"#;

/// `cargo xtask contract [--check]`.
pub fn run(root: &Path, args: &[String]) -> Result<(), String> {
    let check = match args {
        [] => false,
        [flag] if flag == "--check" => true,
        _ => return Err("usage: cargo xtask contract [--check]".into()),
    };
    let text = generate();
    let path = root.join(PATH);
    if check {
        let committed = std::fs::read(&path).map_err(|e| format!("{PATH}: {e}"))?;
        if committed != text.as_bytes() {
            return Err(format!(
                "{PATH} differs from crates/canopen-loader: run `cargo xtask contract` and \
                 commit it"
            ));
        }
        println!("xtask: {PATH} is crates/canopen-loader's");
    } else {
        std::fs::write(&path, text).map_err(|e| format!("{PATH}: {e}"))?;
        println!("xtask: wrote {PATH}");
    }
    Ok(())
}

/// A 32-bit value as the Python sources write addresses and marks: `0x0800_3000`.
fn hex32(value: u32) -> String {
    format!("0x{:04X}_{:04X}", value >> 16, value & 0xFFFF)
}

/// A header offset: `0x14`.
fn hex8(value: usize) -> String {
    format!("0x{value:02X}")
}

/// `CamelCase` -> `CAMEL_CASE`.
fn upper_snake(name: &str) -> String {
    let mut out = String::new();
    for (i, c) in name.chars().enumerate() {
        if c.is_ascii_uppercase() && i > 0 {
            out.push('_');
        }
        out.push(c.to_ascii_uppercase());
    }
    out
}

/// A Python string literal (double quotes), as one line or as an implicit concatenation of
/// lines that each fit after `indent` spaces (split at spaces, each piece ending in one).
fn py_str(text: &str, indent: usize) -> Vec<String> {
    assert!(
        !text.contains(['"', '\\', '\n']),
        "a meaning to quote plainly: {text:?}"
    );
    let room = LINE - indent - 2;
    let mut pieces = vec![String::new()];
    for word in text.split_inclusive(' ') {
        let last = pieces.last_mut().expect("one piece at least");
        if !last.is_empty() && last.len() + word.len() > room {
            pieces.push(String::new());
        }
        pieces.last_mut().expect("one piece").push_str(word);
    }
    pieces.into_iter().map(|p| format!("\"{p}\"")).collect()
}

/// `NAME = value  # comment` lines, the comments aligned as none: ruff keeps two spaces.
fn constant(out: &mut String, name: &str, value: &str, comment: &str) {
    let line = format!("{name} = {value}");
    if comment.is_empty() {
        let _ = writeln!(out, "{line}");
    } else {
        assert!(line.len() + 4 + comment.len() <= LINE, "{name}'s comment");
        let _ = writeln!(out, "{line}  # {comment}");
    }
}

/// The Python module.
pub fn generate() -> String {
    let mut out = String::from(PREAMBLE);

    out.push_str("# The memory map (layout.rs; memory.x at the root, for the linker).\n");
    constant(
        &mut out,
        "PAGE_SIZE",
        &PAGE_SIZE.to_string(),
        "bytes in a flash page",
    );
    constant(
        &mut out,
        "CHIP_FLASH_SIZE",
        &CHIP_FLASH_SIZE.to_string(),
        "bytes of the chip's flash, from LOADER_ORIGIN",
    );
    constant(
        &mut out,
        "LOADER_ORIGIN",
        &hex32(LOADER_ORIGIN),
        "LOADER: the resident loader",
    );
    constant(&mut out, "LOADER_LENGTH", &LOADER_LENGTH.to_string(), "");
    constant(
        &mut out,
        "SLOT_ORIGIN",
        &hex32(SLOT_ORIGIN),
        "the application slot, HEADER then FLASH",
    );
    constant(&mut out, "SLOT_SIZE", &SLOT_SIZE.to_string(), "");
    constant(&mut out, "SLOT_PAGES", &SLOT_PAGES.to_string(), "");
    constant(
        &mut out,
        "HEADER_SLOT",
        &HEADER_SLOT.to_string(),
        "HEADER: the image header, padded with 0xFF",
    );
    constant(
        &mut out,
        "APP_ORIGIN",
        &hex32(APP_ORIGIN),
        "FLASH: the application's vector table",
    );
    constant(
        &mut out,
        "MAX_IMAGE",
        &MAX_IMAGE.to_string(),
        "the most image bytes after the header slot",
    );
    constant(
        &mut out,
        "STORAGE_ORIGIN",
        &hex32(STORAGE_ORIGIN),
        "STORAGE: the parameter pages, never written by the loader",
    );
    constant(&mut out, "STORAGE_LENGTH", &STORAGE_LENGTH.to_string(), "");
    constant(
        &mut out,
        "RAM_ORIGIN",
        &hex32(RAM_ORIGIN),
        "RAM: both images' RAM",
    );
    constant(&mut out, "RAM_LENGTH", &RAM_LENGTH.to_string(), "");

    out.push_str(
        "\n# The image header (header.rs): HEADER_LEN bytes, little-endian, at SLOT_ORIGIN.\n",
    );
    let mark = String::from_utf8_lossy(&MAGIC.to_le_bytes()).into_owned();
    constant(
        &mut out,
        "MAGIC",
        &hex32(MAGIC),
        &format!("the bytes \"{mark}\": the validity mark, written last"),
    );
    constant(&mut out, "FORMAT", &FORMAT.to_string(), "");
    constant(&mut out, "HEADER_LEN", &HEADER_LEN.to_string(), "");
    constant(
        &mut out,
        "UNSET",
        &hex32(UNSET),
        "`length` and `crc` before the seal",
    );
    constant(
        &mut out,
        "MIN_IMAGE",
        &MIN_IMAGE.to_string(),
        "the smallest image: a stack pointer and a reset vector",
    );
    for (name, at) in [
        ("MAGIC_AT", MAGIC_AT),
        ("FORMAT_AT", FORMAT_AT),
        ("HEADER_SIZE_AT", HEADER_SIZE_AT),
        ("VENDOR_ID_AT", VENDOR_ID_AT),
        ("PRODUCT_CODE_AT", PRODUCT_CODE_AT),
        ("VERSION_AT", VERSION_AT),
        ("LENGTH_AT", LENGTH_AT),
        ("CRC_AT", CRC_AT),
        ("RESERVED_AT", RESERVED_AT),
    ] {
        constant(&mut out, name, &hex8(at), "");
    }
    out.push_str("# The fields in order: (name, offset, bytes).\nHEADER_FIELDS = (\n");
    for (name, at, size) in FIELDS {
        let _ = writeln!(out, "    (\"{name}\", {}, {size}),", hex8(at));
    }
    out.push_str(")\n");
    let format: String = FIELDS
        .iter()
        .map(|&(name, _, size)| match size {
            2 => 'H',
            4 => 'I',
            _ => panic!("header field {name}: {size} bytes"),
        })
        .collect();
    constant(
        &mut out,
        "HEADER_STRUCT",
        &format!("\"<{format}\""),
        "the fields for `struct`",
    );

    out.push_str(
        "\n# The hand-off words (layout.rs, boot.rs): the last two words of SRAM, a record and \
         its complement.\n",
    );
    constant(
        &mut out,
        "HANDOFF_ORIGIN",
        &hex32(HANDOFF_ORIGIN),
        "HANDOFF",
    );
    constant(&mut out, "HANDOFF_LENGTH", &HANDOFF_LENGTH.to_string(), "");
    let load = String::from_utf8_lossy(&HANDOFF_REQUEST.to_be_bytes()).into_owned();
    constant(
        &mut out,
        "HANDOFF_REQUEST",
        &hex32(HANDOFF_REQUEST),
        &format!("\"{load}\": the application's request to stay in the loader"),
    );
    let tag = String::from_utf8_lossy(&TRIAL_TAG.to_be_bytes()[..3]).into_owned();
    constant(
        &mut out,
        "TRIAL_TAG",
        &hex32(TRIAL_TAG),
        &format!("\"{tag}\" and the count of unconfirmed starts in the low byte"),
    );
    constant(
        &mut out,
        "MAX_TRIAL_STARTS",
        &MAX_TRIAL_STARTS.to_string(),
        "unconfirmed starts that keep the loader",
    );
    constant(
        &mut out,
        "LISTEN_MS",
        &LISTEN_MS.to_string(),
        "the listening window before every start",
    );

    out.push_str("\n# The loader's identity (node.rs).\n");
    let boot = String::from_utf8_lossy(&DEVICE_TYPE.to_le_bytes()).into_owned();
    constant(
        &mut out,
        "LOADER_DEVICE_TYPE",
        &hex32(DEVICE_TYPE),
        &format!("its 0x1000, the bytes \"{boot}\""),
    );
    constant(
        &mut out,
        "LOADER_PRODUCT_BIT",
        &hex32(LOADER_PRODUCT_BIT),
        "its 0x1018:2 is the application's with this bit set",
    );

    out.push_str(
        "\n# 0x1F57:1, the flash status (program.rs): bit 0 in progress, bits 1-7 the code.\n",
    );
    constant(
        &mut out,
        "FLASH_IN_PROGRESS",
        &hex8(FLASH_IN_PROGRESS as usize),
        "",
    );
    constant(
        &mut out,
        "FLASH_CODE_SHIFT",
        &FLASH_CODE_SHIFT.to_string(),
        "",
    );
    constant(
        &mut out,
        "FLASH_CODE_MASK",
        &hex8(FLASH_CODE_MASK as usize),
        "",
    );
    let names: Vec<String> = FlashStatus::ALL
        .iter()
        .map(|s| format!("FLASH_STATUS_{}", upper_snake(&format!("{s:?}"))))
        .collect();
    for (status, name) in FlashStatus::ALL.iter().zip(&names) {
        constant(&mut out, name, &(*status as u8).to_string(), "");
    }
    out.push_str("# The loader's codes in words.\nFLASH_STATUS_MEANINGS = {\n");
    for (status, name) in FlashStatus::ALL.iter().zip(&names) {
        let one_line = format!("    {name}: \"{}\",", status.meaning());
        if one_line.len() <= LINE {
            let _ = writeln!(out, "{one_line}");
        } else {
            let _ = writeln!(out, "    {name}: (");
            for piece in py_str(status.meaning(), 8) {
                let _ = writeln!(out, "        {piece}");
            }
            out.push_str("    ),\n");
        }
    }
    out.push_str("}\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The committed file is the crate's (what `cargo xtask contract --check` checks, here
    /// also for a plain `cargo test`).
    #[test]
    fn the_committed_file_is_generated_from_the_crate() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let committed = std::fs::read_to_string(root.join(PATH)).unwrap();
        assert!(
            committed == generate(),
            "{PATH} differs from crates/canopen-loader: run `cargo xtask contract`"
        );
    }

    #[test]
    fn lines_fit_and_strings_split_at_spaces() {
        assert!(generate().lines().all(|l| l.len() <= LINE));
        let text = "word ".repeat(40) + "end";
        let pieces = py_str(&text, 8);
        assert!(pieces.len() > 1 && pieces.iter().all(|p| p.len() + 8 <= LINE));
        let joined: String = pieces.iter().map(|p| p.trim_matches('"')).collect();
        assert_eq!(joined, text);
        assert_eq!(upper_snake("NoValidProgram"), "NO_VALID_PROGRAM");
        assert_eq!(hex32(0x0800_3000), "0x0800_3000");
    }

    #[test]
    fn the_names_python_reads_are_there() {
        let text = generate();
        for line in [
            "SLOT_ORIGIN = 0x0800_3000",
            "MAGIC = 0x4D49_5748  # the bytes \"HWIM\"",
            "HEADER_STRUCT = \"<IHHIIIIII\"",
            "TRIAL_TAG = 0x5452_4C00  # \"TRL\"",
            "LOADER_DEVICE_TYPE = 0x544F_4F42  # its 0x1000, the bytes \"BOOT\"",
            "FLASH_STATUS_TRIAL_FAILED = 64",
            "    FLASH_STATUS_OK: \"no error\",",
        ] {
            assert!(text.contains(line), "{line}");
        }
    }
}
