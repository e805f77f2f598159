//! Frame-in / frame-out behaviour of the handwheel device: what a CNC master sees.

mod common;

use common::*;
use handwheel_core::{AbLevels, Axis, FeedRecord, FeedState, FeedStatus, Multiplier, Mutex};

const ENABLED: u8 = 0x01;

#[test]
fn boots_with_bootup_frame_and_no_pdo() {
    let mut b = Bench::new();
    let seen = b.take();
    assert_eq!(seen.len(), 1);
    assert_eq!((seen[0].id, seen[0].data.clone()), (HEARTBEAT, vec![0x00]));
    b.advance_ms(500);
    assert!(b.take_id(TPDO1).is_empty(), "no PDO in Pre-operational");
}

#[test]
fn start_sends_the_default_feed_record() {
    let mut b = Bench::new();
    b.take();
    b.nmt(0x01);
    let pdos = b.take_id(TPDO1);
    assert_eq!(pdos.len(), 1, "TPDO1 on entry to Operational");
    let expected = FeedRecord {
        state: FeedState {
            position: 0,
            axis: None,
            multiplier: Multiplier::X1,
            status: FeedStatus::empty(),
            epoch: 0,
            session: 0,
        },
        sequence: 0,
    };
    assert_eq!(pdos[0].data, expected.to_bytes());
    assert_eq!(b.read_u32(0x2031, 0), 1, "sequence counts the frame sent");
}

#[test]
fn enable_is_refused_outside_operational() {
    let mut b = Bench::new();
    assert_eq!(b.sdo_write(0x2000, 0, &[1]), Err(0x0800_0022));
    assert_eq!(b.read_u32(0x2000, 0), 0);
    b.nmt(0x01);
    assert_eq!(b.sdo_write(0x2000, 0, &[1]), Ok(()));
    assert_eq!(b.read_u32(0x2000, 0), 1);
    assert_eq!(b.sdo_write(0x2000, 0, &[2]), Err(0x0609_0031));
}

#[test]
fn no_feed_before_enable() {
    let mut b = Bench::new();
    b.select(Some(Axis::X), Multiplier::X1);
    b.nmt(0x01);
    b.take();
    b.turn(3);
    b.advance_ms(5);
    let pdos = b.take_id(TPDO1);
    assert!(
        pdos.iter().all(|p| record(p).0 == 0),
        "position never moves"
    );
    assert_eq!(b.read_u32(0x6004, 0), 0);
    assert_eq!(b.read_u32(0x2040, 1), 3, "turning is counted as ignored");
    let status = b.read_u32(0x2030, 0) as u8 & 0x1F; // bits 5-7: the session
    assert_eq!(status, FeedStatus::IGNORED_MOTION.bits());
}

#[test]
fn each_axis_and_multiplier_gives_detents_times_factor() {
    for axis in Axis::ALL {
        for (mult, factor) in [
            (Multiplier::X1, 1),
            (Multiplier::X10, 10),
            (Multiplier::X100, 100),
        ] {
            let mut b = Bench::operational_enabled(axis, mult);
            b.turn(3);
            b.turn(-1);
            b.advance_ms(5);
            let last = b.take_id(TPDO1).last().map(record).unwrap();
            assert_eq!(
                last,
                (
                    2 * factor,
                    axis.object_value(),
                    factor as u8,
                    ENABLED,
                    last.4
                )
            );
            assert_eq!(b.read_u32(0x6004, 0) as i32, 2 * factor);
        }
    }
}

#[test]
fn detent_goes_out_at_once_and_inhibit_time_spaces_frames() {
    let mut b = Bench::operational_enabled(Axis::X, Multiplier::X1);
    let t0 = b.now_us;
    b.turn(1);
    let first = b.take_id(TPDO1);
    assert_eq!(first.len(), 1, "a detent is sent without waiting");
    assert_eq!(first[0].at_us, t0);
    // Two more detents immediately: the inhibit time (2 ms) holds the next frame back, and
    // it then carries both.
    b.turn(2);
    assert!(b.take_id(TPDO1).is_empty());
    b.advance_ms(3);
    let next = b.take_id(TPDO1);
    assert_eq!(next.len(), 1);
    assert_eq!(next[0].at_us, t0 + 2_000);
    assert_eq!(record(&next[0]).0, 3);
}

#[test]
fn event_timer_repeats_the_record_every_100_ms() {
    let mut b = Bench::operational_enabled(Axis::Y, Multiplier::X10);
    b.turn(1);
    b.take();
    b.advance_ms(350);
    let pdos = b.take_id(TPDO1);
    assert_eq!(pdos.len(), 3);
    assert!(pdos.iter().all(|p| record(p).0 == 10));
    let seqs: Vec<u16> = pdos.iter().map(|p| record(p).4).collect();
    assert_eq!(seqs[1], seqs[0].wrapping_add(1));
    assert_eq!(seqs[2], seqs[1].wrapping_add(1));
}

#[test]
fn axis_change_mid_turn_never_moves_the_other_axis() {
    let mut b = Bench::operational_enabled(Axis::X, Multiplier::X1);
    b.turn(2);
    // Half a detent, then the operator switches to Z and finishes the turn.
    for _ in 0..2 {
        b.levels = b.levels.next_forward();
        let l = b.levels;
        b.edge(l);
    }
    // Past the inhibit time, so the switch itself is reported at once.
    b.advance_ms(5);
    let epoch_x = b.read_u32(0x2010, 3);
    b.select(Some(Axis::Z), Multiplier::X1);
    assert_eq!(b.read_u32(0x2010, 3), (epoch_x + 1) & 0xFF);
    b.advance_ms(5);
    for _ in 0..2 {
        b.levels = b.levels.next_forward();
        let l = b.levels;
        b.edge(l);
    }
    b.turn(1);
    b.advance_ms(5);
    let frames: Vec<_> = b.take_id(TPDO1).iter().map(record).collect();
    let on_x: Vec<i32> = frames.iter().filter(|r| r.1 == 1).map(|r| r.0).collect();
    let on_z: Vec<i32> = frames.iter().filter(|r| r.1 == 3).map(|r| r.0).collect();
    assert_eq!(
        on_x.last(),
        Some(&2),
        "X got its two detents and nothing more"
    );
    assert_eq!(on_z.first(), Some(&2), "Z starts from the same position...");
    // The half detent turned on X completes on Z: the operator feels that click with Z
    // selected, so it is Z's motion.
    assert_eq!(on_z.last(), Some(&4), "...and moves by its own two detents");
}

#[test]
fn chatter_nets_zero_and_illegal_jumps_are_counted_with_emcy() {
    let mut b = Bench::operational_enabled(Axis::X, Multiplier::X1);
    let rest = b.levels;
    for _ in 0..50 {
        b.edge(rest.next_forward());
        b.edge(rest);
    }
    b.advance_ms(3);
    assert_eq!(b.read_u32(0x6004, 0), 0);
    assert_eq!(b.read_u32(0x2020, 1), 0);
    b.take();
    // Two illegal jumps: both channels flip.
    b.edge(AbLevels::from_bits(rest.bits() ^ 0b11));
    b.edge(rest);
    b.advance_ms(3);
    assert_eq!(b.read_u32(0x2020, 2), 2);
    let seen = b.take();
    let emcy: Vec<_> = seen.iter().filter(|s| s.id == EMCY).collect();
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].data[..2], [0x00, 0x73]);
    assert_eq!(emcy[0].data[2] & 1, 1, "generic error bit");
    assert_eq!(
        emcy[0].data[3..7],
        [1, 0, 0, 0],
        "illegal count at the first"
    );
    let pdo = seen.iter().rev().find(|s| s.id == TPDO1).unwrap();
    assert_eq!(
        record(pdo).3,
        ENABLED | FeedStatus::ENCODER_ERROR.bits(),
        "status tells the host"
    );
    // A new epoch clears the latched error and the EMCY.
    b.select(Some(Axis::Y), Multiplier::X1);
    b.advance_ms(3);
    let emcy = b.take_id(EMCY);
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].data[..2], [0, 0], "error reset");
}

#[test]
fn unit_step_stream_matches_the_papers_format() {
    let mut b = Bench::new();
    b.select(Some(Axis::X), Multiplier::X1);
    b.sdo_write(0x2001, 0, &[1]).unwrap();
    b.nmt(0x01);
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    b.advance_ms(5);
    b.take();
    b.turn(4);
    b.advance_ms(20);
    b.turn(-4);
    b.advance_ms(20);
    let steps = b.take_id(TPDO2);
    let bytes: Vec<u8> = steps.iter().map(|s| s.data[0]).collect();
    assert_eq!(bytes, [0x08, 0x18, 0x28, 0x38, 0x40, 0x50, 0x60, 0x70]);
    assert!(steps.iter().all(|s| s.data.len() == 1));
    for pair in steps.windows(2) {
        assert!(
            pair[1].at_us - pair[0].at_us >= 2_000,
            "inhibit paces steps"
        );
    }
}

#[test]
fn unit_step_backlog_is_bounded_at_x100() {
    let mut b = Bench::new();
    b.select(Some(Axis::Z), Multiplier::X100);
    b.sdo_write(0x2001, 0, &[1]).unwrap();
    b.nmt(0x01);
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    b.advance_ms(5);
    b.take();
    b.turn(1);
    let stopped_at = b.now_us;
    b.advance_ms(300);
    let steps = b.take_id(TPDO2);
    assert_eq!(steps.len(), 40, "the default bound");
    let run_on = steps.last().unwrap().at_us - stopped_at;
    assert!(run_on < 100_000, "run-on {run_on} us");
    assert_eq!(b.read_u32(0x2040, 2), 60, "dropped steps are counted");
    assert_eq!(
        b.read_u32(0x2030, 0) as u8 & FeedStatus::STEPS_DROPPED.bits(),
        FeedStatus::STEPS_DROPPED.bits()
    );
}

#[test]
fn leaving_operational_stops_feed_and_discards_steps() {
    let mut b = Bench::new();
    b.select(Some(Axis::X), Multiplier::X10);
    b.sdo_write(0x2001, 0, &[1]).unwrap();
    b.nmt(0x01);
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    b.turn(1);
    b.nmt(0x80);
    assert_eq!(b.read_u32(0x2000, 0), 0, "feed disabled");
    b.take();
    b.nmt(0x01);
    b.advance_ms(100);
    assert!(b.take_id(TPDO2).is_empty(), "no stale steps after restart");
}

#[test]
fn master_heartbeat_loss_stops_feed_with_emcy_8130() {
    let mut b = Bench::operational_enabled(Axis::X, Multiplier::X1);
    // Monitor node 1 with a 100 ms timeout.
    b.sdo_write(0x1016, 1, &(0x0001_0064u32).to_le_bytes())
        .unwrap();
    b.receive(0x701, &[0x05]);
    b.advance_ms(50);
    b.receive(0x701, &[0x05]);
    b.turn(1);
    b.advance_ms(50);
    assert_eq!(b.read_u32(0x2000, 0), 1, "still alive");
    b.take();
    b.advance_ms(120);
    let seen = b.take();
    let emcy: Vec<_> = seen.iter().filter(|s| s.id == EMCY).collect();
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].data[..2], [0x30, 0x81]);
    let last = seen
        .iter()
        .rev()
        .find(|s| s.id == TPDO1)
        .map(record)
        .unwrap();
    assert_eq!(last.0, 1);
    assert_eq!(
        last.3,
        FeedStatus::MASTER_LOST.bits(),
        "disabled, master lost"
    );
    b.turn(2);
    b.advance_ms(5);
    assert_eq!(b.read_u32(0x6004, 0), 1, "no feed after the loss");
    // The master comes back and must enable again.
    b.receive(0x701, &[0x05]);
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    b.turn(1);
    assert_eq!(b.read_u32(0x6004, 0), 2);
}

/// While the monitored master stays silent, feed cannot be switched back on,
/// the wheel moves nothing, and the record keeps saying why.
#[test]
fn feed_cannot_be_enabled_while_the_master_is_lost() {
    let mut b = Bench::operational_enabled(Axis::X, Multiplier::X1);
    b.sdo_write(0x1016, 1, &(0x0001_00C8u32).to_le_bytes())
        .unwrap();
    b.receive(0x701, &[0x05]);
    b.advance_ms(250);
    assert_eq!(b.read_u32(0x2000, 0), 0, "the loss disabled feed");
    assert_eq!(b.read_u32(0x1001, 0), 0x11);
    // A write from somewhere else on the bus, the master still silent.
    assert_eq!(b.sdo_write(0x2000, 0, &[1]), Err(0x0800_0022));
    b.take();
    b.turn(4);
    b.advance_ms(50);
    assert_eq!(b.read_u32(0x6004, 0), 0, "no feed while the master is lost");
    assert_eq!(b.read_u32(0x2000, 0), 0);
    let status = b.read_u32(0x2030, 0) as u8 & 0x1F; // bits 5-7: the session
    assert_ne!(
        status & FeedStatus::MASTER_LOST.bits(),
        0,
        "bit 3 still says why"
    );
    assert_eq!(status & FeedStatus::ENABLED.bits(), 0);
    assert!(b
        .take_id(TPDO1)
        .iter()
        .all(|s| record(s).0 == 0 && record(s).3 & FeedStatus::MASTER_LOST.bits() != 0));
    assert_eq!(b.read_u32(0x1001, 0), 0x11);
    // Disabling stays allowed, and the master's return makes enabling possible again.
    b.sdo_write(0x2000, 0, &[0]).unwrap();
    b.receive(0x701, &[0x05]);
    assert_eq!(b.read_u32(0x1001, 0), 0);
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    let status = b.read_u32(0x2030, 0) as u8 & 0x1F; // bits 5-7: the session
    assert_eq!(
        status,
        FeedStatus::ENABLED.bits(),
        "bit 3 clears with the new enable"
    );
    b.turn(2);
    assert_eq!(b.read_u32(0x6004, 0), 2);
}

#[test]
fn decoder_parameters_are_checked_and_applied() {
    let mut b = Bench::operational_enabled(Axis::X, Multiplier::X1);
    assert_eq!(b.sdo_write(0x2020, 3, &[3]), Err(0x0609_0030));
    assert_eq!(b.sdo_write(0x2020, 3, &[5]), Err(0x0609_0031));
    assert_eq!(b.sdo_write(0x2020, 3, &[0]), Err(0x0609_0032));
    assert_eq!(b.read_u32(0x2020, 3), 4, "rejected writes change nothing");
    b.sdo_write(0x2020, 3, &[2]).unwrap();
    b.sdo_write(0x2020, 4, &[1]).unwrap();
    b.turn(1); // 4 counts forward = 2 detents, inverted
    assert_eq!(b.read_u32(0x6004, 0) as i32, -2);
    assert_eq!(b.read_u32(0x2020, 1) as i32, -4);
    assert_eq!(b.sdo_write(0x2030, 0, &[0]), Err(0x0601_0002));
    assert_eq!(b.sdo_write(0x6004, 0, &[0, 0, 0, 0]), Err(0x0601_0002));
    assert_eq!(b.sdo_write(0x2000, 0, &[1, 0, 0, 0]), Err(0x0607_0012));
}

#[test]
fn stored_wheel_parameters_survive_reset_node_and_restore_defaults() {
    let mut b = Bench::new();
    b.sdo_write(0x2020, 3, &[2]).unwrap();
    b.sdo_write(0x2040, 3, &100u16.to_le_bytes()).unwrap();
    b.sdo_write(0x1010, 3, b"save").unwrap();
    b.nmt(0x81);
    assert_eq!(b.read_u32(0x2020, 3), 2);
    assert_eq!(b.read_u32(0x2040, 3), 100);
    assert_eq!(b.read_u32(0x2000, 0), 0, "enable is never stored");
    b.sdo_write(0x1011, 1, b"load").unwrap();
    b.nmt(0x81);
    assert_eq!(b.read_u32(0x2020, 3), 4);
    assert_eq!(b.read_u32(0x2040, 3), 40);
}

#[test]
fn nothing_is_stored_while_the_feed_is_enabled() {
    // Writing flash stalls the CPU and with it the wheel's edges: 0x1010, 0x1011 and LSS
    // store are refused (0x08000022, LSS 255 / 2) while the feed is on, and work once off.
    let mut b = Bench::operational_enabled(Axis::X, Multiplier::X1);
    b.sdo_write(0x2020, 3, &[2]).unwrap();
    for sub in 1..=3 {
        assert_eq!(b.sdo_write(0x1010, sub, b"save"), Err(0x0800_0022));
        assert_eq!(b.sdo_write(0x1011, sub, b"load"), Err(0x0800_0022));
    }
    b.receive(0x7E5, &[0x04, 1, 0, 0, 0, 0, 0, 0]);
    b.take();
    b.receive(0x7E5, &[0x17, 0, 0, 0, 0, 0, 0, 0]);
    let lss: Vec<Vec<u8>> = b.take_id(0x7E4).into_iter().map(|s| s.data).collect();
    assert_eq!(lss, vec![vec![0x17, 255, 2, 0, 0, 0, 0, 0]]);
    assert_eq!(b.device.engine().storage().writes(), 0);
    assert_eq!(b.device.engine().storage().node(), None);
    // The wheel kept going meanwhile.
    b.turn(3);
    assert_eq!(b.read_u32(0x6004, 0), 6, "12 counts at 2 counts per detent");
    // Feed off: stores go through.
    b.sdo_write(0x2000, 0, &[0]).unwrap();
    b.sdo_write(0x1010, 1, b"save").unwrap();
    b.receive(0x7E5, &[0x17, 0, 0, 0, 0, 0, 0, 0]);
    let lss: Vec<Vec<u8>> = b.take_id(0x7E4).into_iter().map(|s| s.data).collect();
    assert_eq!(lss, vec![vec![0x17, 0, 0, 0, 0, 0, 0, 0]]);
    assert_eq!(b.device.engine().storage().writes(), 1);
    b.nmt(0x81);
    assert_eq!(b.read_u32(0x2020, 3), 2, "stored");
}

#[test]
fn reset_node_keeps_the_selector_but_zeroes_the_feed() {
    let mut b = Bench::operational_enabled(Axis::W, Multiplier::X10);
    b.turn(2);
    let (sequence, epoch) = (b.read_u32(0x2031, 0) as u16, b.read_u32(0x2010, 3) as u8);
    b.nmt(0x81);
    assert_eq!(b.read_u32(0x6004, 0), 0);
    assert_eq!(b.read_u32(0x2010, 1), 4, "W still selected");
    assert_eq!(b.read_u32(0x2010, 2), 10);
    // The sequence and the epoch go on, with a break: the first record after the reset can
    // never be taken for a continuation of one before it.
    let gap = (b.read_u32(0x2031, 0) as u16).wrapping_sub(sequence);
    assert_eq!(gap, u16::from(handwheel_core::MAX_DROP_GAP), "a full break");
    assert_ne!(b.read_u32(0x2010, 3) as u8, epoch);
}

fn unit_step_mode(axis: Axis, mult: Multiplier) -> Bench {
    let mut b = Bench::new();
    b.select(Some(axis), mult);
    b.sdo_write(0x2001, 0, &[1]).unwrap();
    b.nmt(0x01);
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    b.advance_ms(5);
    b.take();
    b
}

#[test]
fn a_step_waiting_for_inhibit_is_withdrawn_by_an_axis_change() {
    // Found by the property test: the step prepared for X must not go out once the axis
    // switch has left X, even though TPDO2 was already requested.
    let mut b = unit_step_mode(Axis::X, Multiplier::X1);
    b.turn(2);
    assert_eq!(
        b.take_id(TPDO2).len(),
        1,
        "first step at once, second waits"
    );
    b.select(None, Multiplier::X1);
    b.advance_ms(50);
    assert!(b.take_id(TPDO2).is_empty());
}

#[test]
fn an_event_timer_on_tpdo2_never_repeats_a_step() {
    let mut b = unit_step_mode(Axis::Y, Multiplier::X1);
    // An integrator sets a 10 ms event timer on the unit-step PDO.
    b.sdo_write(0x1801, 5, &10u16.to_le_bytes()).unwrap();
    b.turn(1);
    b.advance_ms(100);
    let bytes: Vec<u8> = b.take_id(TPDO2).iter().map(|s| s.data[0]).collect();
    assert_eq!(bytes, [0x09], "one step, never repeated");
}

/// The position is an I32 that wraps: across the wrap every record still differs from the
/// previous one by exactly the motion, taken as a wrapping difference, as a host applies it.
#[test]
fn position_wraps_and_the_host_difference_stays_exact() {
    let mut b = Bench::operational_enabled(Axis::Y, Multiplier::X100);
    // A long spin delivered at once: 21 474 836 detents x 100 = i32::MAX - 47.
    b.wheel.lock(|w| w.feed.add_detents(21_474_836));
    // Straight into the accumulator, which marks a record due itself.
    b.advance_ms(100);
    let start = record(b.take_id(TPDO1).last().expect("a record")).0;
    assert_eq!(start, i32::MAX - 47);
    let mut host = start;
    let mut applied: i64 = 0;
    for (detents, expected) in [
        (1, i32::MIN + 52),
        (2, i32::MIN + 252),
        (-4, i32::MAX - 147),
    ] {
        b.turn(detents);
        b.advance_ms(5);
        for r in b.take_id(TPDO1).iter().map(record) {
            applied += i64::from(r.0.wrapping_sub(host));
            host = r.0;
        }
        assert_eq!(host, expected, "after {detents}");
    }
    assert_eq!(applied, -100, "1 + 2 - 4 detents at x100");
    assert_eq!(b.read_u32(0x6004, 0) as i32, i32::MAX - 147);
}
