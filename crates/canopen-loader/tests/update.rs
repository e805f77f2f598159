//! The loader on the bus: its objects, a complete update, and every refusal of the
//! contract's table (docs/FIRMWARE-UPDATE.md) with its 0x1F57 code and SDO abort.

mod common;

use canopen_loader::layout::{APP_ORIGIN, HEADER_SLOT, MAX_IMAGE, PAGE_SIZE, SLOT_SIZE};
use canopen_loader::{seal, DeviceId, ImageHeader};
use common::{
    header_of, image, image_for, mix, Bench, Transfer, DEVICE, HEARTBEAT, LOADER_REVISION, SDO_TX,
    SERIAL,
};

const NOT_CLEARED: u32 = 0x0800_0022;
const FORMAT_UNKNOWN: u32 = 0x0609_0030;
const FORMAT_ERROR: u32 = 0x0800_0020;
const WRITE_ERROR: u32 = 0x0606_0000;
const ADDRESS_ERROR: u32 = 0x0504_0005;

/// A loader over an erased slot, cleared.
fn cleared() -> Bench {
    let mut bench = Bench::boot(common::erased_slot());
    bench.write(0x1F51, 1, &[3]).unwrap();
    bench
}

#[test]
fn the_loader_says_what_it_is() {
    let mut bench = Bench::boot(common::erased_slot());
    assert_eq!(bench.read(0x1000, 0), Ok(0x544F_4F42));
    assert_eq!(bench.read(0x1001, 0), Ok(0));
    assert_eq!(bench.read(0x1017, 0), Ok(1000));
    assert_eq!(bench.read(0x1018, 0), Ok(4));
    assert_eq!(bench.read(0x1018, 1), Ok(DEVICE.vendor_id));
    assert_eq!(bench.read(0x1018, 2), Ok(DEVICE.product_code | 1 << 31));
    assert_eq!(bench.read(0x1018, 3), Ok(LOADER_REVISION));
    assert_eq!(bench.read(0x1018, 4), Ok(SERIAL));
    for index in [0x1F50, 0x1F51, 0x1F56, 0x1F57] {
        assert_eq!(bench.read(index, 0), Ok(1), "{index:#x}");
    }
    // No valid application: stopped, no software, "no valid program".
    assert_eq!(bench.program_state(), (0, 0, 1 << 1));
    assert_eq!(bench.read(0x1F50, 1), Err(0x0601_0001));
    assert_eq!(bench.read(0x1F50, 2), Err(0x0609_0011));
    assert_eq!(bench.read(0x1018, 5), Err(0x0609_0011));
    assert_eq!(bench.read(0x2000, 0), Err(0x0602_0000));
    assert_eq!(bench.read(0x1010, 1), Err(0x0602_0000));
    assert_eq!(bench.write(0x1000, 0, &[1, 2, 3, 4]), Err(0x0601_0002));
    assert_eq!(bench.write(0x1F56, 1, &[1, 2, 3, 4]), Err(0x0601_0002));
    assert_eq!(bench.write(0x1F57, 1, &[1, 2, 3, 4]), Err(0x0601_0002));
    assert_eq!(bench.write(0x1017, 0, &[1]), Err(0x0607_0013));
    assert_eq!(bench.write(0x1F51, 1, &[3, 0]), Err(0x0607_0012));
}

#[test]
fn a_complete_update_then_start() {
    let file = image(7, 5 * PAGE_SIZE + 3);
    let header = header_of(&file);
    let mut bench = Bench::boot(common::erased_slot());
    bench.write(0x1F51, 1, &[0]).unwrap();
    bench.write(0x1F51, 1, &[3]).unwrap();
    assert_eq!(bench.program_state(), (3, 0, 0));
    bench.download(&file, Transfer::of(&file)).unwrap();
    assert_eq!(bench.program_state(), (0, header.crc, 0));
    assert_eq!(bench.valid(), Some(header));
    assert!(common::slot_holds(&bench.flash, &file));
    // Past the image, the slot is as it was (erased here).
    assert!(bench.flash.bytes[file.len()..].iter().all(|&b| b == 0xFF));

    // Start: answered first, then the reset (the boot decision starts the application).
    let sent = bench.receive(common::SDO_RX, &[0x2F, 0x51, 0x1F, 1, 1, 0, 0, 0]);
    assert_eq!(sent.len(), 1);
    assert_eq!(
        (sent[0].id(), sent[0].data()),
        (SDO_TX, &[0x60, 0x51, 0x1F, 1, 0, 0, 0, 0][..])
    );
    assert_eq!(bench.resets, 1);

    // A loader booted over it reports the application's CRC.
    let mut again = Bench::boot(bench.flash.powered_up());
    assert_eq!(again.program_state(), (0, header.crc, 0));
}

#[test]
fn program_control_values() {
    let mut bench = Bench::boot(common::erased_slot());
    // Start without a valid application: refused.
    assert_eq!(bench.write(0x1F51, 1, &[1]), Err(NOT_CLEARED));
    assert_eq!(bench.write(0x1F51, 1, &[2]), Err(FORMAT_UNKNOWN));
    for other in [4, 0x80, 0xFF] {
        assert_eq!(bench.write(0x1F51, 1, &[other]), Err(FORMAT_UNKNOWN));
    }
    assert_eq!(bench.resets, 0);
    // Writes refused unless Pre-operational.
    bench.nmt(0x01);
    assert_eq!(bench.write(0x1F51, 1, &[3]), Err(NOT_CLEARED));
    assert_eq!(bench.write(0x1F51, 1, &[0]), Err(NOT_CLEARED));
    assert_eq!(bench.read(0x1F51, 1), Ok(0));
    bench.nmt(0x80);
    assert_eq!(bench.write(0x1F51, 1, &[3]), Ok(()));
    assert_eq!(bench.read(0x1F51, 1), Ok(3));
    // Stop changes nothing in the loader.
    assert_eq!(bench.write(0x1F51, 1, &[0]), Ok(()));
    assert_eq!(bench.read(0x1F51, 1), Ok(3));
}

#[test]
fn clear_invalidates_a_valid_application() {
    let file = image(1, 2000);
    let mut bench = cleared();
    bench.download(&file, Transfer::of(&file)).unwrap();
    assert!(bench.valid().is_some());
    bench.write(0x1F51, 1, &[3]).unwrap();
    assert_eq!(bench.valid(), None);
    assert_eq!(bench.program_state(), (3, 0, 0));
    assert_eq!(&bench.flash.bytes[..PAGE_SIZE], &[0xFF; PAGE_SIZE][..]);
    assert_eq!(bench.write(0x1F51, 1, &[1]), Err(NOT_CLEARED));
}

#[test]
fn data_before_clear() {
    let file = image(1, 2000);
    let mut bench = Bench::boot(common::erased_slot());
    assert_eq!(bench.download(&file, Transfer::of(&file)), Err(NOT_CLEARED));
    assert_eq!(bench.program_state(), (0, 0, 4 << 1));
    // Expedited, too.
    assert_eq!(bench.write(0x1F50, 1, &[1, 2, 3, 4]), Err(NOT_CLEARED));
    // After a complete download, another needs a clear; the application stays valid.
    bench.update(&file).unwrap();
    let crc = header_of(&file).crc;
    assert_eq!(bench.download(&file, Transfer::of(&file)), Err(NOT_CLEARED));
    assert_eq!(bench.program_state(), (0, crc, 4 << 1));
    assert_eq!(bench.valid(), Some(header_of(&file)));
}

/// After a failure: stopped, no application, the code; the next download needs a clear, and
/// a clear and a good image then work.
fn assert_failed(bench: &mut Bench, code: u32) {
    assert_eq!(bench.program_state(), (0, 0, code << 1));
    assert_eq!(bench.valid(), None);
    let good = image(9, 1500);
    assert_eq!(bench.download(&good, Transfer::of(&good)), Err(NOT_CLEARED));
    assert_eq!(bench.update(&good), Ok(()));
    assert_eq!(bench.valid(), Some(header_of(&good)));
}

#[test]
fn another_devices_image() {
    for device in [
        DeviceId {
            vendor_id: DEVICE.vendor_id + 1,
            ..DEVICE
        },
        DeviceId {
            product_code: DEVICE.product_code | 1 << 31,
            ..DEVICE
        },
    ] {
        let file = image_for(device, 1, 2000, 5);
        let mut bench = cleared();
        assert_eq!(
            bench.download(&file, Transfer::of(&file)),
            Err(FORMAT_UNKNOWN)
        );
        // Refused at the header: nothing past the header page's erase was written.
        assert!(bench.flash.bytes.iter().all(|&b| b == 0xFF));
        assert_failed(&mut bench, 2);
    }
}

#[test]
fn unknown_mark_format_or_size() {
    for (at, value) in [(0, b'X'), (3, 0x4E), (4, 2), (6, 33)] {
        let mut file = image(1, 2000);
        file[at] = value;
        let mut bench = cleared();
        assert_eq!(
            bench.download(&file, Transfer::of(&file)),
            Err(FORMAT_UNKNOWN),
            "{at}"
        );
        assert_failed(&mut bench, 2);
    }
    // A stream shorter than the header ends short.
    let mut bench = cleared();
    let file = image(1, 2000);
    let how = Transfer {
        size: None,
        segment: 7,
        seed: None,
    };
    assert_eq!(bench.download(&file[..20], how), Err(FORMAT_ERROR));
    assert_failed(&mut bench, 3);
}

#[test]
fn a_bad_crc() {
    let mut file = image(1, 3000);
    file[HEADER_SLOT + 1234] ^= 0x10;
    let mut bench = cleared();
    assert_eq!(
        bench.download(&file, Transfer::of(&file)),
        Err(FORMAT_ERROR)
    );
    assert_eq!(&bench.flash.bytes[..4], &[0xFF; 4], "no mark");
    assert_failed(&mut bench, 3);
    // The header's CRC itself wrong.
    let mut file = image(1, 3000);
    file[0x18] ^= 1;
    let mut bench = cleared();
    assert_eq!(
        bench.download(&file, Transfer::of(&file)),
        Err(FORMAT_ERROR)
    );
    assert_failed(&mut bench, 3);
}

#[test]
fn an_implausible_vector_table() {
    for (at, value) in [
        // Stack pointer in flash.
        (0u32, 0x0800_4000u32),
        // Stack pointer past RAM.
        (0, 0x2000_5000),
        // Reset vector without the Thumb bit, one past the image, one in the header.
        (4, APP_ORIGIN + 0x100),
        (4, APP_ORIGIN + 1 + 3000),
        (4, APP_ORIGIN - 0x100 + 1),
    ] {
        let mut file = image(1, 3000);
        let at = HEADER_SLOT + at as usize;
        file[at..at + 4].copy_from_slice(&value.to_le_bytes());
        seal(&mut file).unwrap();
        let mut bench = cleared();
        assert_eq!(
            bench.download(&file, Transfer::of(&file)),
            Err(FORMAT_ERROR)
        );
        assert_failed(&mut bench, 3);
    }
}

#[test]
fn too_large_for_the_slot() {
    // The indicated size: refused at the initiate.
    let file = image(1, 2000);
    let mut bench = cleared();
    let how = Transfer {
        size: Some(SLOT_SIZE as u32 + 1),
        ..Transfer::of(&file)
    };
    assert_eq!(bench.download(&file, how), Err(ADDRESS_ERROR));
    assert_failed(&mut bench, 6);
    // The slot's size exactly is accepted at the initiate (and then fails short).
    let mut bench = cleared();
    let how = Transfer {
        size: Some(SLOT_SIZE as u32),
        ..Transfer::of(&file)
    };
    assert_eq!(bench.download(&file, how), Err(FORMAT_ERROR));
    assert_failed(&mut bench, 3);
    // The header's length, with no size indicated: refused when the header is complete.
    let mut file = image(1, 2000);
    file[0x14..0x18].copy_from_slice(&(MAX_IMAGE as u32 + 1).to_le_bytes());
    let mut bench = cleared();
    let how = Transfer {
        size: None,
        segment: 7,
        seed: None,
    };
    assert_eq!(bench.download(&file, how), Err(ADDRESS_ERROR));
    assert_failed(&mut bench, 6);
}

#[test]
fn the_largest_image_fits() {
    let file = image(1, MAX_IMAGE);
    assert_eq!(file.len(), SLOT_SIZE);
    let mut bench = cleared();
    assert_eq!(bench.download(&file, Transfer::of(&file)), Ok(()));
    assert_eq!(bench.valid(), Some(header_of(&file)));
}

#[test]
fn short_and_long_streams() {
    let file = image(1, 2000);
    // Size indicated and right, but the stream ends early: the last segment comes short.
    let mut bench = cleared();
    let how = Transfer {
        size: None,
        segment: 7,
        seed: None,
    };
    assert_eq!(
        bench.download(&file[..file.len() - 1], how),
        Err(FORMAT_ERROR)
    );
    assert_failed(&mut bench, 3);
    // An indicated size that does not match the header's length: refused at the header.
    for size in [file.len() - 1, file.len() + 1] {
        let mut bench = cleared();
        let how = Transfer {
            size: Some(size as u32),
            ..Transfer::of(&file)
        };
        assert_eq!(bench.download(&file, how), Err(FORMAT_ERROR), "{size}");
        assert_failed(&mut bench, 3);
    }
    // No size, a byte past `length`.
    let mut long = file.clone();
    long.push(0xFF);
    let mut bench = cleared();
    assert_eq!(bench.download(&long, how), Err(FORMAT_ERROR));
    assert_failed(&mut bench, 3);
}

#[test]
fn a_flash_that_fails() {
    let file = image(1, 2000);
    // The erase of clear.
    let mut flash = common::erased_slot();
    flash.fail_at = Some(0);
    let mut bench = Bench::boot(flash);
    assert_eq!(bench.write(0x1F51, 1, &[3]), Err(WRITE_ERROR));
    assert_failed(&mut bench, 5);
    // A program in the stream, an erase on the way (the first op after clear's erase and the
    // header's 14 half-words is the page 1 erase at byte 1024), and the mark.
    let ops = {
        let mut b = cleared();
        let start = b.flash.ops;
        b.download(&file, Transfer::of(&file)).unwrap();
        b.flash.ops - start
    };
    for fail in [3, 14, 100, ops - 2, ops - 1] {
        let mut bench = cleared();
        bench.flash.fail_at = Some(bench.flash.ops + fail);
        assert_eq!(
            bench.download(&file, Transfer::of(&file)),
            Err(WRITE_ERROR),
            "{fail}"
        );
        assert_failed(&mut bench, 5);
    }
}

#[test]
fn odd_segment_sizes() {
    for seed in 0..40u64 {
        let mut s = seed;
        let length = 8 + (mix(&mut s) % 4000) as usize;
        let file = image_for(DEVICE, seed as u32, length, seed);
        let mut bench = cleared();
        for segment in [1, 2, 3, 5, 6, 7] {
            if seed % 6 == segment as u64 % 6 {
                let how = Transfer {
                    segment,
                    ..Transfer::of(&file)
                };
                bench.download(&file, how).unwrap();
                break;
            }
        }
        if bench.valid().is_none() {
            let how = Transfer {
                seed: Some(seed),
                ..Transfer::of(&file)
            };
            bench.download(&file, how).unwrap();
        }
        assert_eq!(
            bench.valid(),
            Some(header_of(&file)),
            "seed {seed}, {length} bytes"
        );
        assert!(common::slot_holds(&bench.flash, &file));
    }
}

#[test]
fn program_takes_any_chunking() {
    // The state machine alone, chunks of 1..=100 bytes.
    use canopen_loader::Program;
    for seed in 0..20u64 {
        let mut s = seed + 1000;
        let file = image_for(DEVICE, 1, 1 + (mix(&mut s) % 3000) as usize + 7, seed);
        let mut flash = common::erased_slot();
        let mut program = Program::new(DEVICE, &flash);
        program.write_control(3, &mut flash).unwrap();
        program.begin(None).unwrap();
        assert_eq!(program.flash_status(), 1, "in progress");
        let mut at = 0;
        while at < file.len() {
            let n = (1 + (mix(&mut s) % 100) as usize).min(file.len() - at);
            program.write(&file[at..at + n], &mut flash).unwrap();
            at += n;
        }
        program.finish(&mut flash).unwrap();
        assert_eq!(program.flash_status(), 0);
        assert_eq!(program.software_id(), header_of(&file).crc);
        assert_eq!(
            canopen_loader::valid_application(&flash, DEVICE),
            Some(header_of(&file))
        );
    }
}

#[test]
fn an_aborted_or_timed_out_transfer_fails_the_download() {
    let file = image(1, 2000);
    // The client aborts mid-stream.
    let mut bench = cleared();
    bench.sdo([0x21, 0x50, 0x1F, 1, 0xD0, 0x07, 0, 0]);
    bench.sdo([0x00, 1, 2, 3, 4, 5, 6, 7]);
    assert_eq!(bench.read(0x1F57, 1), Ok(1), "in progress");
    let sent = bench.receive(common::SDO_RX, &[0x80, 0x50, 0x1F, 1, 0, 0, 4, 5]);
    assert!(sent.is_empty());
    assert_failed(&mut bench, 3);
    // The client goes quiet: the SDO timeout aborts it.
    let mut bench = cleared();
    bench.sdo([0x21, 0x50, 0x1F, 1, 0xD0, 0x07, 0, 0]);
    bench.sdo([0x00, 1, 2, 3, 4, 5, 6, 7]);
    let sent = bench.advance_ms(1001);
    let aborts: Vec<_> = sent.iter().filter(|f| f.id() == SDO_TX).collect();
    assert_eq!(aborts.len(), 1);
    assert_eq!(aborts[0].data(), &[0x80, 0x50, 0x1F, 1, 0, 0, 0x04, 0x05]);
    assert_failed(&mut bench, 3);
    // NMT stopped mid-stream.
    let mut bench = cleared();
    bench.sdo([0x21, 0x50, 0x1F, 1, 0xD0, 0x07, 0, 0]);
    bench.nmt(0x02);
    bench.nmt(0x80);
    assert_failed(&mut bench, 3);
    // A repeated segment (toggle not alternated).
    let mut bench = cleared();
    bench.sdo([0x21, 0x50, 0x1F, 1, 0xD0, 0x07, 0, 0]);
    bench.sdo([0x00, 1, 2, 3, 4, 5, 6, 7]);
    let answer = bench.sdo([0x00, 1, 2, 3, 4, 5, 6, 7]);
    assert_eq!(answer, [0x80, 0x50, 0x1F, 1, 0, 0, 0x03, 0x05]);
    assert_failed(&mut bench, 3);
    let _ = file;
}

#[test]
fn an_expedited_download_is_a_short_stream() {
    let mut bench = cleared();
    assert_eq!(
        bench.write(0x1F50, 1, &[0x48, 0x57, 0x49, 0x4D]),
        Err(FORMAT_ERROR)
    );
    assert_failed(&mut bench, 3);
}

#[test]
fn nmt_and_heartbeat() {
    let mut bench = Bench::boot(common::erased_slot());
    let beats = |frames: &[canopen_slave::Frame]| -> Vec<Vec<u8>> {
        frames
            .iter()
            .filter(|f| f.id() == HEARTBEAT)
            .map(|f| f.data().to_vec())
            .collect()
    };
    // First heartbeat one period after the boot-up.
    assert!(beats(&bench.advance_ms(999)).is_empty());
    assert_eq!(beats(&bench.advance_ms(1)), [[0x7F]]);
    // State changes are announced.
    assert_eq!(beats(&bench.nmt(0x01)), [[0x05]]);
    assert_eq!(beats(&bench.nmt(0x02)), [[0x04]]);
    // Stopped: no SDO.
    assert!(bench
        .receive(common::SDO_RX, &[0x40, 0, 0x10, 0, 0, 0, 0, 0])
        .is_empty());
    assert_eq!(beats(&bench.nmt(0x80)), [[0x7F]]);
    // 0x1017 rw, takes effect at once.
    bench.write(0x1017, 0, &100u16.to_le_bytes()).unwrap();
    assert_eq!(bench.read(0x1017, 0), Ok(100));
    assert!(beats(&bench.advance_ms(99)).is_empty());
    assert_eq!(beats(&bench.advance_ms(1)), [[0x7F]]);
    bench.write(0x1017, 0, &[0, 0]).unwrap();
    assert!(beats(&bench.advance_ms(3000)).is_empty());
    assert_eq!(bench.node.next_deadline(), None);
    // Reset communication: boot-up again, 0x1017 back to its default (not stored).
    assert_eq!(beats(&bench.nmt(0x82)), [[0x00]]);
    assert_eq!(bench.read(0x1017, 0), Ok(1000));
    // Reset node: the shell resets the system.
    assert_eq!(bench.resets, 0);
    assert!(bench.nmt(0x81).is_empty());
    assert_eq!(bench.resets, 1);
    // Broadcast commands count, other nodes' do not.
    bench.receive(0x000, &[0x01, 0]);
    assert_eq!(bench.node.state(), canopen_slave::NmtState::Operational);
    bench.receive(0x000, &[0x80, 0x22]);
    assert_eq!(bench.node.state(), canopen_slave::NmtState::Operational);
}

#[test]
fn sealed_files_are_what_the_loader_checks() {
    let file = image(3, 100);
    let header = ImageHeader::parse(&file).unwrap();
    assert_eq!(header.length, 100);
    assert_eq!(header.crc, canopen_loader::crc32(&file[HEADER_SLOT..]));
    assert_eq!(header.check(DEVICE), Ok(()));
}
