//! Power cuts during an update, exhaustively: before and inside every flash operation of
//! "clear", of the streamed program data and of the validity mark. After each cut the board
//! boots from what the flash holds: the boot decision finds the new application (only once
//! the mark is complete) or none (the loader stays and answers SDO), never a partial image;
//! nothing outside the slot is written (the flash model is the slot and panics past it); and
//! a fresh loader takes a complete second update.

mod common;

use canopen_loader::layout::PAGE_SIZE;
use canopen_loader::{Flash, MAGIC};
use common::{header_of, image, Bench, Cut, CutFlash};

/// A flash holding `old` as a complete, valid update.
fn with_old(old: &[u8]) -> CutFlash {
    let mut bench = Bench::boot(common::erased_slot());
    bench.update(old).unwrap();
    assert_eq!(bench.valid(), Some(header_of(old)));
    bench.flash.powered_up()
}

/// The update of `new` over `before`, cut at `cut`; the flash afterwards.
fn cut_update(before: &CutFlash, new: &[u8], cut: Option<Cut>) -> CutFlash {
    let mut flash = before.powered_up();
    flash.cut = cut;
    let mut bench = Bench::boot(flash);
    // With the power off the answers mean nothing: what counts is the flash.
    let _ = bench.update(new);
    bench.flash
}

/// Which part of the update an operation belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Clear,
    Stream,
    Mark,
}

#[test]
fn a_cut_anywhere_boots_the_new_image_or_the_loader() {
    // Three pages and an odd length: the stream erases pages 1 and 2 on its way and ends
    // with a half-word of one byte.
    let old = image(1, 2 * PAGE_SIZE + 101);
    let new = image(2, 2 * PAGE_SIZE + 301);
    let new_header = header_of(&new);
    let before = with_old(&old);

    let ops = cut_update(&before, &new, None).ops;
    // 1 erase at clear, 2 erases on the way, the half-words of the image that are not
    // 0xFFFF, 2 of the mark.
    assert!(ops > 1 + 2 + 2 + 1000, "{ops} operations");
    let phase = |op: usize| match op {
        0 => Phase::Clear,
        n if n + 2 >= ops => Phase::Mark,
        _ => Phase::Stream,
    };

    let mut tried = 0;
    for op in 0..ops {
        let mut cuts = vec![Cut::Before(op)];
        cuts.extend((1..=3).map(|s| Cut::Inside(op, s * 7919 + op as u64)));
        for cut in cuts {
            tried += 1;
            // Only the slot is written: the model is the slot, and panics past it.
            let after = cut_update(&before, &new, Some(cut)).powered_up();
            let mut bench = Bench::boot(after);
            let valid = bench.valid();
            match phase(op) {
                Phase::Clear => assert!(
                    valid.is_none() || valid == Some(header_of(&old)),
                    "{cut:?} in clear: {valid:?}"
                ),
                Phase::Stream => assert_eq!(valid, None, "{cut:?} in the stream"),
                Phase::Mark => {
                    let mark = u32::from_le_bytes(bench.flash.bytes[..4].try_into().unwrap());
                    match valid {
                        None => assert_ne!(mark, MAGIC, "{cut:?}: a complete mark is valid"),
                        Some(h) => {
                            assert_eq!(h, new_header, "{cut:?}");
                            assert_eq!(mark, MAGIC);
                            assert!(common::slot_holds(&bench.flash, &new), "{cut:?}");
                        }
                    }
                }
            }
            // The loader stays (or would be left by the boot decision) and answers.
            assert_eq!(bench.read(0x1000, 0), Ok(0x544F_4F42), "{cut:?}");
            let (control, id, status) = bench.program_state();
            assert_eq!(control, 0);
            match valid {
                Some(h) => assert_eq!((id, status), (h.crc, 0), "{cut:?}"),
                None => assert_eq!((id, status), (0, 1 << 1), "{cut:?}"),
            }
            // The next update goes through.
            let third = image(3, PAGE_SIZE + 77);
            assert_eq!(bench.update(&third), Ok(()), "{cut:?}: second update");
            assert_eq!(bench.valid(), Some(header_of(&third)), "{cut:?}");
            assert_eq!(bench.program_state(), (0, header_of(&third).crc, 0));
        }
    }
    assert_eq!(tried, 4 * ops);
}

/// A cut during a second clear, after a cut inside the stream (the slot's pages past the
/// header page hold a half-written image), then a complete update: every cut of the second
/// clear leaves no valid image.
#[test]
fn a_cut_clear_over_a_cut_stream() {
    let new = image(2, 3 * PAGE_SIZE);
    let before = with_old(&image(1, 3 * PAGE_SIZE));
    let stream_cut = cut_update(&before, &new, Some(Cut::Inside(900, 5))).powered_up();
    for cut in [Cut::Before(0), Cut::Inside(0, 1), Cut::Inside(0, 2)] {
        let after = cut_update(&stream_cut, &new, Some(cut)).powered_up();
        let mut bench = Bench::boot(after);
        assert_eq!(bench.valid(), None, "{cut:?}");
        assert_eq!(bench.update(&new), Ok(()));
        assert_eq!(bench.valid(), Some(header_of(&new)));
    }
}

#[test]
fn a_stream_that_ends_short_leaves_the_mark_erased() {
    let new = image(4, 1000);
    let mut bench = Bench::boot(with_old(&image(1, 3000)));
    bench.write(0x1F51, 1, &[3]).unwrap();
    let short = &new[..new.len() - 3];
    let how = common::Transfer {
        size: None,
        segment: 7,
        seed: None,
    };
    assert_eq!(bench.download(short, how), Err(0x0800_0020));
    // The header went to flash as it arrived, but for the mark.
    assert_eq!(&bench.flash.bytes[..4], &[0xFF; 4]);
    assert_eq!(&bench.flash.bytes[4..32], &new[4..32]);
    assert_eq!(bench.valid(), None);
    assert_eq!(bench.program_state(), (0, 0, 3 << 1));
}

/// An updater without the loader's order: it erases the pages, then programs the file as it
/// comes, the mark first (the file starts with it).
fn naive_update(flash: &mut CutFlash, file: &[u8]) -> bool {
    for page in 0..file.len().div_ceil(PAGE_SIZE) {
        if flash.erase(page).is_err() {
            return false;
        }
    }
    for (i, pair) in file.chunks(2).enumerate() {
        let value = u16::from_le_bytes([pair[0], pair.get(1).copied().unwrap_or(0xFF)]);
        if value != 0xFFFF
            && handwheel_board::flash::program_half_word(flash, 2 * i, value).is_err()
        {
            return false;
        }
    }
    true
}

/// The cuts find the hole they guard against: with the mark programmed first, a cut in the
/// stream leaves a slot that carries a complete mark over a partial image, which a boot
/// check of the mark alone would start. The loader's boot check (the CRC over the image)
/// refuses every one of them; its own order (`a_cut_anywhere_boots_the_new_image_or_the_loader`)
/// never makes one.
#[test]
fn the_cuts_find_a_mark_written_first() {
    let new = image(2, 2 * PAGE_SIZE + 301);
    let mut marked_but_partial = 0;
    let mut op = 0;
    loop {
        let mut flash = common::erased_slot();
        flash.cut = Some(Cut::Inside(op, 17 + op as u64));
        let finished = naive_update(&mut flash, &new);
        let after = flash.powered_up();
        let mark = u32::from_le_bytes(after.bytes[..4].try_into().unwrap());
        if mark == MAGIC && !common::slot_holds(&after, &new) {
            marked_but_partial += 1;
            assert_eq!(Bench::boot(after).valid(), None, "cut inside {op}");
        }
        if finished {
            break;
        }
        op += 1;
    }
    assert!(op > 1000, "{op} operations");
    assert!(
        marked_but_partial > op / 2,
        "{marked_but_partial} of {op} cuts left a mark over a partial image"
    );
}
