//! The boot decision across resets (docs/FIRMWARE-UPDATE.md, "Trial boot"): the record in
//! the `HANDOFF` words as the loader, the application and the power see it, over any
//! sequence of starts, confirmations, resets and power-ons; the window's request; 0x1F57
//! code 64 in the loader.

mod common;

use canopen_loader::boot::{MAX_TRIAL_STARTS, TRIAL_TAG};
use canopen_loader::layout::HANDOFF_REQUEST;
use canopen_loader::{is_rescue_request, Boot, BootRecord, StayReason};
use canopen_slave::{Frame, NodeId};
use common::{image, Bench, NODE, SDO_RX};

/// The board as the boot decision sees it: the two words (SRAM: kept by a reset, lost at a
/// power-on) and whether the slot's application is valid.
struct Board {
    words: [u32; 2],
    valid: bool,
    /// What the loader did at each reset.
    boots: Vec<Boot>,
}

impl Board {
    fn new(valid: bool) -> Self {
        Self {
            words: [0, 0],
            valid,
            boots: Vec::new(),
        }
    }

    /// A reset: the loader decides, keeps what it keeps, and (nobody asking in the window)
    /// counts the start. Returns whether the application runs now.
    fn reset(&mut self) -> bool {
        let valid = self.valid;
        let boot = Boot::decide(BootRecord::decode(self.words), || valid);
        self.words = boot.record_kept().encode();
        self.boots.push(boot);
        match boot {
            Boot::Listen { starts } => {
                self.words = Boot::record_at_start(starts).encode();
                true
            }
            Boot::Stay(_) => false,
        }
    }

    fn power_on(&mut self) -> bool {
        self.words = [0, 0];
        self.reset()
    }

    /// The application is healthy on the bus: it clears the words.
    fn confirm(&mut self) {
        self.words = [0, 0];
    }

    /// The application's 0x1F51 "stop".
    fn stop(&mut self) -> bool {
        self.words = [HANDOFF_REQUEST, !HANDOFF_REQUEST];
        self.reset()
    }

    fn starts(&self) -> Option<u8> {
        match BootRecord::decode(self.words) {
            BootRecord::Trial { starts } => Some(starts),
            _ => None,
        }
    }
}

#[test]
fn an_application_that_never_confirms_gets_three_starts_then_the_loader_stays() {
    let mut board = Board::new(true);
    for start in 1..=MAX_TRIAL_STARTS {
        assert!(board.reset(), "start {start}");
        assert_eq!(board.starts(), Some(start));
        // A hang, a fault, a lock-up: the watchdog resets.
    }
    assert!(!board.reset());
    assert_eq!(
        board.boots.last(),
        Some(&Boot::Stay(StayReason::TrialFailed))
    );
    // A reset node or NRST keeps the loader: the record stays.
    for _ in 0..5 {
        assert!(!board.reset());
        assert_eq!(board.starts(), Some(MAX_TRIAL_STARTS));
    }
    // A power-on is a fresh trial: three more starts.
    assert!(board.power_on());
    assert_eq!(board.starts(), Some(1));
    assert!(board.reset() && board.reset() && !board.reset());
}

#[test]
fn a_confirmed_application_survives_any_number_of_resets() {
    let mut board = Board::new(true);
    for _ in 0..20 {
        assert!(board.reset());
        assert_eq!(board.starts(), Some(1));
        board.confirm();
    }
    // Two unconfirmed, a confirmed one in between: the count starts again.
    assert!(board.reset() && board.reset());
    assert_eq!(board.starts(), Some(2));
    board.confirm();
    assert!(board.reset() && board.reset() && board.reset());
    assert!(!board.reset(), "three in a row");
}

#[test]
fn a_power_on_at_any_point_of_a_trial_starts_afresh() {
    for cut_after in 0..=MAX_TRIAL_STARTS {
        let mut board = Board::new(true);
        assert!(board.power_on());
        for _ in 1..cut_after {
            assert!(board.reset());
        }
        // The power fails; SRAM is lost.
        assert!(board.power_on(), "after {cut_after} starts");
        assert_eq!(board.starts(), Some(1));
    }
}

#[test]
fn the_stay_request_and_an_invalid_slot_keep_the_loader_and_are_used_once() {
    let mut board = Board::new(true);
    assert!(board.reset());
    board.confirm();
    assert!(!board.stop());
    assert_eq!(board.boots.last(), Some(&Boot::Stay(StayReason::Requested)));
    assert_eq!(board.words, [0, 0], "the request is taken");
    assert!(board.reset(), "the next reset starts the application");
    // A stay request is taken whatever count came before it.
    let mut failed = Board::new(true);
    while failed.reset() {}
    assert!(!failed.stop());
    assert_eq!(
        failed.boots.last(),
        Some(&Boot::Stay(StayReason::Requested))
    );
    let mut empty = Board::new(false);
    assert!(!empty.power_on());
    assert_eq!(
        empty.boots.last(),
        Some(&Boot::Stay(StayReason::NoValidProgram))
    );
    assert_eq!(empty.words, [0, 0]);
}

#[test]
fn the_validity_check_runs_only_when_it_decides() {
    let mut asked = 0;
    let trial = BootRecord::Trial {
        starts: MAX_TRIAL_STARTS,
    };
    for record in [BootRecord::StayRequest, trial] {
        let _ = Boot::decide(record, || {
            asked += 1;
            true
        });
    }
    assert_eq!(asked, 0, "a request or a failed trial costs no CRC");
    assert_eq!(
        Boot::decide(BootRecord::Trial { starts: 2 }, || true),
        Boot::Listen { starts: 2 }
    );
    assert_eq!(TRIAL_TAG & 0xFF, 0);
}

fn frame(id: u16, data: [u8; 8]) -> Frame {
    Frame::new(id, &data).unwrap()
}

#[test]
fn the_window_takes_only_0x1f51_stop_to_this_node() {
    let node = NodeId::new(NODE).unwrap();
    let stop = |command: u8, value: u8| {
        frame(SDO_RX, [command, 0x51, 0x1F, 0x01, value, 0x00, 0x00, 0x00])
    };
    // Expedited downloads of 0 as masters write them: 1 byte indicated, 4 bytes, none.
    for command in [0x2F, 0x2B, 0x23, 0x22] {
        assert!(is_rescue_request(&stop(command, 0), node), "{command:#x}");
    }
    let others = [
        stop(0x2F, 1),                                           // start
        stop(0x2F, 3),                                           // clear
        stop(0x40, 0),                                           // an upload
        stop(0x21, 0),                                           // a segmented download
        frame(SDO_RX, [0x2F, 0x51, 0x1F, 0x02, 0, 0, 0, 0]),     // another sub-index
        frame(SDO_RX, [0x2F, 0x50, 0x1F, 0x01, 0, 0, 0, 0]),     // another object
        frame(SDO_RX + 1, [0x2F, 0x51, 0x1F, 0x01, 0, 0, 0, 0]), // another node
        frame(0x000, [0x80, NODE, 0, 0, 0, 0, 0, 0]),            // NMT pre-operational
        frame(0x000, [0x81, 0, 0, 0, 0, 0, 0, 0]),               // NMT reset all
    ];
    for other in others {
        assert!(!is_rescue_request(&other, node), "{other:?}");
    }
    let short = Frame::new(SDO_RX, &[0x2F, 0x51, 0x1F, 0x01, 0x00]).unwrap();
    assert!(!is_rescue_request(&short, node));
}

#[test]
fn the_loader_says_the_trial_failed_until_the_next_clear() {
    let file = image(5, 2000);
    let with_image = || {
        let mut bench = Bench::boot(common::erased_slot());
        bench.update(&file).unwrap();
        bench
    };
    let mut bench = with_image();
    assert_eq!(bench.read(0x1F57, 1), Ok(0));
    bench.node.report_failed_trial();
    assert_eq!(bench.read(0x1F57, 1), Ok(64 << 1), "code 64");
    assert_eq!(bench.read(0x1F56, 1).map(|crc| crc != 0), Ok(true));
    bench.write(0x1F51, 1, &[3]).unwrap();
    assert_eq!(bench.read(0x1F57, 1), Ok(0));
    // And a start from the loader is allowed: the image is valid.
    let mut again = with_image();
    again.node.report_failed_trial();
    let resets = again.resets;
    again.write(0x1F51, 1, &[1]).unwrap();
    assert_eq!(again.resets, resets + 1);
}
