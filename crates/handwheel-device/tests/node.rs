//! The step function the firmware's `canopen` task runs (`Node::poll`): joining the bus,
//! LEDs, the acceptance filter, the sleep it allows, LSS bit-rate switches, lost frames and a
//! stalled transmit path, through a fake CAN port.

use std::collections::VecDeque;

use canopen_slave::{BusEvent, BusState, Frame, FrameSink, MemoryStorage, NodeId, SinkFull};
use handwheel_core::{
    AbLevels, Axis, BitRate, DecoderConfig, LinkedWheel, Multiplier, SelectorInput,
};
use handwheel_device::{CanIo, HandwheelDevice, Node, Outputs, TransmitState};

const NODE: u8 = 5;

/// The CAN port: frames in and out, and the controller as the test sets it.
#[derive(Default)]
struct Port {
    rx: VecDeque<Frame>,
    sent: Vec<Frame>,
    /// The controller joins the bus at a rate when asked for it (a free bus).
    bus_free: bool,
    /// The rates the node asked the controller to step to.
    steps: Vec<BitRate>,
    /// Another node acknowledged a frame of ours.
    acknowledged: bool,
    bus: Option<BusState>,
    rx_overruns: u32,
    /// Frames wait for a bus that takes nothing.
    blocked: bool,
    /// The path ran empty between two rounds (reported once).
    ran_empty: bool,
    /// The round is held up this long before the port reads the transmit path's state (an
    /// interrupt storm preempts it; the transmit interrupt keeps draining the path).
    held_up_ms: u32,
    discards: usize,
}

impl FrameSink for Port {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        self.sent.push(frame);
        Ok(())
    }

    fn discard_pending(&mut self) {
        self.discards += 1;
    }
}

impl CanIo for Port {
    fn receive(&mut self) -> Option<Frame> {
        self.rx.pop_front()
    }

    fn bus_state(&mut self) -> BusState {
        self.bus.unwrap_or(BusState::ErrorActive)
    }

    fn rx_overruns(&mut self) -> u32 {
        self.rx_overruns
    }

    fn transmit_state(&mut self) -> TransmitState {
        TransmitState {
            waiting: self.blocked,
            ran_empty: std::mem::take(&mut self.ran_empty),
        }
    }

    fn dated_transmit_state(&mut self, now_ms: u32) -> (TransmitState, u32) {
        (self.transmit_state(), now_ms + self.held_up_ms)
    }

    fn switch_bit_rate(&mut self, rate: BitRate) -> bool {
        self.steps.push(rate);
        self.bus_free
    }

    fn frame_acknowledged(&mut self) -> bool {
        self.acknowledged
    }
}

/// The switch lines: axis X at x1 unless a test moves them (active low bits as read).
struct Lines(u8, u8);

impl SelectorInput for Lines {
    fn read_lines(&mut self) -> (u8, u8) {
        (self.0, self.1)
    }
}

struct Rig {
    node: Node<MemoryStorage>,
    port: Port,
    lines: Lines,
    wheel: LinkedWheel<handwheel_core::EdgeState>,
}

impl Rig {
    fn new(bus_free: bool) -> Self {
        let node_id = NodeId::new(NODE).unwrap();
        let device = HandwheelDevice::new(node_id, 0x1234_5678, MemoryStorage::new());
        Self {
            node: Node::new(device, BitRate::Kbit1000),
            port: Port {
                bus_free,
                ..Port::default()
            },
            lines: Lines(1, 1),
            wheel: LinkedWheel::local(DecoderConfig::default(), AbLevels::from_bits(0)),
        }
    }

    fn poll(&mut self, ms: u32) -> Outputs {
        self.node
            .poll(ms, &mut self.port, &mut self.lines, &mut self.wheel)
    }

    /// Receives `data` on `id` and runs a round at `ms`.
    fn receive(&mut self, ms: u32, id: u16, data: &[u8]) -> Outputs {
        self.port.rx.push_back(Frame::new(id, data).unwrap());
        self.poll(ms)
    }

    fn sent_on(&self, id: u16) -> Vec<Vec<u8>> {
        let sent = self.port.sent.iter().filter(|f| f.id() == id);
        sent.map(|f| f.data().to_vec()).collect()
    }
}

fn sdo_write_u32(index: u16, sub: u8, value: u32) -> [u8; 8] {
    let [a, b, c, d] = value.to_le_bytes();
    [0x23, index as u8, (index >> 8) as u8, sub, a, b, c, d]
}

#[test]
fn on_a_free_bus_the_node_boots_up_at_its_first_round() {
    let mut r = Rig::new(true);
    let out = r.poll(0);
    assert_eq!(r.port.steps, [BitRate::Kbit1000]);
    assert_eq!(r.sent_on(0x700 + u16::from(NODE)), [vec![0u8]]);
    assert!(!out.log.on_bus, "no wait, nothing to report");
    assert_eq!(out.log.no_recessive_bits, None);
    assert_eq!(out.sleep_ms, 0, "the switch sample is due at once");
    assert_eq!(out.rx_filter, None, "the filter init programmed is right");
    assert_eq!(r.node.rx_filter().sync(), 0x080);
    assert_eq!(r.node.rx_filter().sdo_request(), 0x605);
}

#[test]
fn on_a_dead_bus_the_node_waits_with_err_on_and_boots_once_it_is_free() {
    let mut r = Rig::new(false);
    let out = r.poll(1000);
    assert_eq!(
        out.leds,
        Some((false, false)),
        "Initialising: RUN dark, no error yet"
    );
    assert_eq!(out.sleep_ms, 1, "a switch under way is looked at every ms");
    for ms in 1001..1050 {
        let out = r.poll(ms);
        assert_eq!(out.log.no_recessive_bits, None, "{ms}");
    }
    let out = r.poll(1050);
    assert_eq!(
        out.log.no_recessive_bits,
        Some((BitRate::Kbit1000, true)),
        "once, at the limit, as a boot-time wait"
    );
    assert_eq!(out.leds, Some((false, true)), "bus-off: ERR on, RUN dark");
    assert_eq!(out.sleep_ms, 10, "off the bus: recovery polling");
    for ms in (1060..3000).step_by(10) {
        let out = r.poll(ms);
        assert_eq!(out.log.no_recessive_bits, None, "reported once");
        assert!(!out.log.on_bus);
    }
    assert!(r.port.sent.is_empty(), "no frame before the boot-up");
    assert!(r.port.steps.len() > 100);
    assert!(r.port.steps.iter().all(|&rate| rate == BitRate::Kbit1000));
    r.port.bus_free = true;
    let out = r.poll(3000);
    assert!(out.log.on_bus, "the reported wait is over");
    assert_eq!(r.sent_on(0x705), [vec![0u8]]);
    let leds: Vec<_> = (3050..3450).step_by(50).map(|ms| r.poll(ms)).collect();
    assert!(leds.iter().all(|out| !out.log.on_bus), "once");
    let run: Vec<bool> = leds.iter().map(|out| out.leds.unwrap().0).collect();
    // Pre-operational: RUN blinks (200 ms on from each multiple of 400 ms), ERR off.
    assert_eq!(run, [false, false, false, true, true, true, true, false]);
    assert!(leds.iter().all(|out| !out.leds.unwrap().1));
}

#[test]
fn leds_show_the_nmt_state_and_the_bus_state() {
    let mut r = Rig::new(true);
    r.poll(0);
    // Pre-operational: RUN blinking (200 ms on, 200 ms off), ERR off.
    let run: Vec<bool> = (0..8).map(|i| r.poll(i * 50).leds.unwrap().0).collect();
    assert_eq!(run, [true, true, true, true, false, false, false, false]);
    r.receive(400, 0x000, &[0x01, NODE]);
    let out = r.poll(450);
    assert_eq!(out.leds, Some((true, false)), "Operational: RUN on");
    r.port.bus = Some(BusState::Warning);
    let out = r.poll(500);
    assert_eq!(out.log.bus, Some(BusEvent::WarningLimit));
    // Single flash: 200 ms on, then off until 1200 ms in the pattern's period.
    assert_eq!(
        out.leds,
        Some((true, false)),
        "500 ms is in the pause after the flash"
    );
    let out = r.poll(1200);
    assert_eq!(out.leds, Some((true, true)), "the flash");
    r.port.bus = Some(BusState::BusOff);
    let out = r.poll(1250);
    assert_eq!(out.log.bus, Some(BusEvent::BusOff));
    assert_eq!(out.leds, Some((true, true)), "bus-off: ERR on");
    let out = r.poll(1400);
    assert_eq!(out.leds, Some((true, true)));
}

#[test]
fn the_filter_follows_a_write_of_0x1005_and_a_reset_of_communication() {
    let mut r = Rig::new(true);
    r.poll(0);
    let out = r.receive(10, 0x605, &sdo_write_u32(0x1005, 0, 0x0000_0091));
    assert_eq!(r.sent_on(0x585), [vec![0x60, 0x05, 0x10, 0, 0, 0, 0, 0]]);
    let filter = out.rx_filter.expect("SYNC moved");
    assert_eq!(filter.sync(), 0x091);
    assert_eq!(filter.sdo_request(), 0x605);
    assert_eq!(r.poll(20).rx_filter, None, "programmed once");
    let out = r.receive(30, 0x000, &[0x82, NODE]);
    assert_eq!(
        out.rx_filter.map(|f| f.sync()),
        Some(0x080),
        "back to the default"
    );
    assert_eq!(r.node.rx_filter().sync(), 0x080);
}

#[test]
fn the_filter_takes_the_second_sdo_server_once_0x1201_makes_it_valid() {
    let mut r = Rig::new(true);
    r.poll(0);
    assert_eq!(
        r.node.rx_filter().second_sdo_request(),
        0x605,
        "none: a repeat"
    );
    let out = r.receive(10, 0x605, &sdo_write_u32(0x1201, 1, 0x685));
    assert_eq!(out.rx_filter, None, "0x1201:2 not valid yet");
    let out = r.receive(20, 0x605, &sdo_write_u32(0x1201, 2, 0x695));
    let filter = out.rx_filter.expect("the second server is valid");
    assert_eq!(filter.second_sdo_request(), 0x685);
    assert!(filter.accepts(0x685) && filter.accepts(0x605));
    assert_eq!(filter.sync(), 0x080);
    // The server answers on its own identifier from the same round on.
    r.port.sent.clear();
    r.receive(30, 0x685, &[0x40, 0x17, 0x10, 0, 0, 0, 0, 0]);
    assert_eq!(
        r.sent_on(0x695),
        [vec![0x4B, 0x17, 0x10, 0, 0xE8, 0x03, 0, 0]]
    );
    assert_eq!(r.sent_on(0x585), Vec::<Vec<u8>>::new());
    // Given up, and after a reset of communication: the repeat again.
    let out = r.receive(40, 0x605, &sdo_write_u32(0x1201, 1, 0x8000_0685));
    assert_eq!(out.rx_filter.map(|f| f.second_sdo_request()), Some(0x605));
    r.receive(50, 0x605, &sdo_write_u32(0x1201, 1, 0x685));
    assert_eq!(r.node.rx_filter().second_sdo_request(), 0x685);
    let out = r.receive(60, 0x000, &[0x82, NODE]);
    assert_eq!(out.rx_filter.map(|f| f.second_sdo_request()), Some(0x605));
}

#[test]
fn the_sleep_is_the_nearest_of_duties_device_and_bit_rate_switch() {
    let mut r = Rig::new(true);
    r.poll(0);
    assert_eq!(r.poll(0).sleep_ms, 5, "the next switch sample");
    // A producer heartbeat of 3 ms: its deadline comes before the sample.
    r.receive(1, 0x605, &[0x2B, 0x17, 0x10, 0, 3, 0, 0, 0]);
    let out = r.poll(2);
    assert_eq!(out.sleep_ms, 2, "heartbeat due at 4 ms, sample at 5 ms");
    // Heartbeat off, an error state: recovery polling caps nothing below 5 ms here, but a
    // bit-rate switch under way does (1 ms).
    r.receive(3, 0x605, &[0x2B, 0x17, 0x10, 0, 0, 0, 0, 0]);
    r.port.bus_free = false;
    r.receive(4, 0x7E5, &[0x04, 1, 0, 0, 0, 0, 0, 0]);
    r.receive(4, 0x7E5, &[0x13, 0, 3, 0, 0, 0, 0, 0]);
    let out = r.receive(4, 0x7E5, &[0x15, 2, 0, 0, 0, 0, 0, 0]);
    assert_eq!(out.sleep_ms, 1, "until the switch delay (2 ms) ends");
    let out = r.poll(6);
    assert_eq!(out.log.bit_rate, Some(BitRate::Kbit250));
    assert_eq!(out.sleep_ms, 1, "a switch under way: every ms");
}

#[test]
fn an_lss_switch_steps_the_controller_and_one_that_never_joins_is_bus_off() {
    let mut r = Rig::new(true);
    r.poll(0);
    r.port.steps.clear();
    r.port.bus_free = false;
    r.receive(10, 0x7E5, &[0x04, 1, 0, 0, 0, 0, 0, 0]);
    r.receive(10, 0x7E5, &[0x13, 0, 3, 0, 0, 0, 0, 0]);
    assert_eq!(r.sent_on(0x7E4), [vec![0x13, 0, 0, 0, 0, 0, 0, 0]]);
    r.receive(10, 0x7E5, &[0x15, 10, 0, 0, 0, 0, 0, 0]);
    assert!(r.poll(19).log.bit_rate.is_none(), "before the switch delay");
    assert!(r.port.steps.is_empty());
    let out = r.poll(20);
    assert_eq!(out.log.bit_rate, Some(BitRate::Kbit250));
    assert_eq!(
        r.port.steps,
        [BitRate::Kbit250],
        "the first step in the same round"
    );
    for ms in 21..70 {
        assert_eq!(r.poll(ms).log.no_recessive_bits, None);
    }
    let out = r.poll(70);
    assert_eq!(out.log.no_recessive_bits, Some((BitRate::Kbit250, false)));
    assert_eq!(
        out.sleep_ms, 5,
        "off the bus: no 1 ms polling, the sample is next"
    );
    let out = r.poll(71);
    assert_eq!(
        out.log.bus,
        Some(BusEvent::BusOff),
        "off the bus counts as bus-off"
    );
    let emcy = 0x080 + u16::from(NODE);
    let before = r.sent_on(emcy).len();
    assert_eq!(
        r.poll(100).leds,
        Some((true, true)),
        "RUN blinking (on), ERR on"
    );
    r.port.bus_free = true;
    r.poll(110);
    let out = r.poll(111);
    assert_eq!(out.log.bus, Some(BusEvent::BusOffRecovered));
    let emcys = r.sent_on(emcy);
    assert_eq!(emcys.len(), before + 2, "{emcys:x?}");
    assert_eq!(emcys[before][..2], [0x40, 0x81], "EMCY 0x8140");
    assert_eq!(
        emcys[before + 1],
        [0; 8],
        "an event: the error reset follows"
    );
    let steps = r.port.steps.len();
    r.poll(120);
    assert_eq!(r.port.steps.len(), steps, "on the bus: no more steps");
}

#[test]
fn lost_frames_raise_emcy_8110_once_per_loss() {
    let mut r = Rig::new(true);
    r.poll(0);
    r.port.rx_overruns = 3;
    let out = r.poll(5);
    assert_eq!(out.log.rx_lost, 3);
    let emcys = r.sent_on(0x085);
    assert_eq!(emcys.len(), 2, "{emcys:x?}");
    assert_eq!(
        emcys[0][..3],
        [0x10, 0x81, 0x11],
        "0x8110, communication error bit"
    );
    assert_eq!(emcys[1], [0; 8], "an event: the error reset follows");
    assert_eq!(r.poll(10).log.rx_lost, 0);
    assert_eq!(r.sent_on(0x085).len(), 2);
    r.port.rx_overruns = u32::MAX;
    assert_eq!(r.poll(15).log.rx_lost, u32::MAX - 3);
    r.port.rx_overruns = 1; // the count wrapped
    assert_eq!(r.poll(20).log.rx_lost, 2);
}

#[test]
fn a_transmit_path_stalled_for_100_ms_stops_the_feed_and_discards() {
    let mut r = Rig::new(true);
    r.poll(0);
    r.receive(1, 0x000, &[0x01, NODE]);
    r.receive(2, 0x605, &[0x2F, 0x00, 0x20, 0, 1, 0, 0, 0]);
    assert_eq!(r.sent_on(0x585).last().unwrap()[0], 0x60, "feed enabled");
    r.port.blocked = true;
    let out = r.poll(10);
    assert!(out.sleep_ms <= 5);
    for ms in (15..110).step_by(5) {
        r.poll(ms);
        assert_eq!(r.port.discards, 0, "{ms}");
    }
    r.poll(110);
    assert_eq!(
        r.port.discards, 1,
        "100 ms after the path was first seen waiting"
    );
    r.port.blocked = false;
    r.receive(120, 0x605, &[0x40, 0x00, 0x20, 0, 0, 0, 0, 0]);
    assert_eq!(
        r.sent_on(0x585).last().unwrap()[..5],
        [0x4F, 0x00, 0x20, 0, 0],
        "the feed was disabled"
    );
    // Queued after the discard, so it reaches the master once frames get out again: EMCY
    // 0x8100 with manufacturer byte 1 (transmit path blocked), then the error reset.
    let emcys = r.sent_on(0x085);
    let blocked = emcys
        .iter()
        .position(|e| e[..2] == [0x00, 0x81])
        .expect("EMCY 0x8100");
    assert_eq!(
        emcys[blocked][3], 0x01,
        "manufacturer byte 0: transmit path blocked"
    );
    assert_ne!(emcys[blocked][2] & 0x10, 0, "error register: communication");
    assert_eq!(
        emcys.get(blocked + 1).map(|e| e[..3].to_vec()),
        Some(vec![0, 0, 0])
    );
}

#[test]
fn a_blocked_path_stops_the_feed_once_until_it_runs_empty() {
    // (A bus that lets a frame out now and then, which the fake port cannot show, is
    // tests/interop/test_copies.py's trickling-bus test and the feed checker's setting.)
    let mut r = Rig::new(true);
    r.poll(0);
    r.receive(1, 0x000, &[0x01, NODE]);
    r.port.blocked = true;
    r.poll(5);
    r.poll(105);
    assert_eq!(r.port.discards, 1);
    for ms in (110..=1000).step_by(10) {
        r.poll(ms);
    }
    assert_eq!(
        r.port.discards, 1,
        "no second stop while the path has not run empty"
    );
}

#[test]
fn a_path_that_ran_empty_between_two_rounds_counts_afresh() {
    // Rounds held up (a long flash write, an interrupt storm) while the transmit interrupt
    // drained the path: what waits at the next round is new, whatever waited before.
    let mut r = Rig::new(true);
    r.poll(0);
    r.receive(1, 0x000, &[0x01, NODE]);
    r.port.blocked = true;
    r.poll(2);
    r.port.ran_empty = true;
    r.poll(90);
    r.poll(150);
    assert_eq!(r.port.discards, 0, "waiting since 90 ms, not since 2 ms");
    r.poll(190);
    assert_eq!(r.port.discards, 1, "100 ms after the path last ran empty");
}

#[test]
fn a_round_held_up_after_its_tick_dates_the_path_when_it_read_it() {
    // tests/interop/test_hostile.py's receive overrun: the board's `stall` preempts the round
    // that began at 2 ms for 200 ms, the transmit interrupt drains the path meanwhile and
    // the receive interrupt loses frames. At 202 ms the round goes on: EMCY 0x8110 is queued
    // behind the path that ran empty, and the state is read. Frames wait since 202 ms, not
    // since the round's tick: the next round, at 202 ms, finds them still on their way.
    let mut r = Rig::new(true);
    r.poll(0);
    r.receive(1, 0x000, &[0x01, NODE]);
    r.port.rx_overruns = 25;
    r.port.ran_empty = true;
    r.port.blocked = true;
    r.port.held_up_ms = 200;
    assert_eq!(r.poll(2).log.rx_lost, 25);
    r.port.held_up_ms = 0;
    r.poll(202);
    assert_eq!(r.port.discards, 0, "frames waiting since 202 ms, not 2 ms");
    let emcys = r.sent_on(0x085);
    assert!(
        emcys.iter().all(|e| e[..2] != [0x00, 0x81]),
        "no EMCY 0x8100: {emcys:x?}"
    );
    r.poll(301);
    assert_eq!(r.port.discards, 0);
    r.poll(302);
    assert_eq!(r.port.discards, 1, "100 ms after the state was read");
}

#[test]
fn feed_stays_off_until_a_blocked_path_has_drained() {
    let mut r = Rig::new(true);
    r.poll(0);
    r.receive(1, 0x000, &[0x01, NODE]);
    r.port.blocked = true;
    r.poll(2);
    r.poll(102);
    assert_eq!(r.port.discards, 1);
    // The master's enable arrives while the path still holds frames: refused (0x08000022),
    // since the records would queue behind frames the bus does not take.
    r.receive(110, 0x605, &[0x2F, 0x00, 0x20, 0, 1, 0, 0, 0]);
    assert_eq!(
        r.sent_on(0x585).last().unwrap()[..],
        [0x80, 0x00, 0x20, 0, 0x22, 0x00, 0x00, 0x08]
    );
    r.port.blocked = false;
    r.poll(120);
    r.receive(121, 0x605, &[0x2F, 0x00, 0x20, 0, 1, 0, 0, 0]);
    assert_eq!(
        r.sent_on(0x585).last().unwrap()[0],
        0x60,
        "enabled once drained"
    );
    // A new block is a new stop.
    r.port.blocked = true;
    r.poll(130);
    r.poll(230);
    assert_eq!(r.port.discards, 2);
}

#[test]
fn a_debounced_selection_reaches_the_device_and_the_log() {
    let mut r = Rig::new(true);
    r.poll(0);
    // Axis Z (line 2), x100 (line 2), as the lines read them: active bits.
    r.lines = Lines(1 << 2, 1 << 2);
    let mut seen = Vec::new();
    for ms in (5..=40).step_by(5) {
        if let Some(selection) = r.poll(ms).log.selection {
            seen.push((ms, selection.axis, selection.multiplier));
        }
    }
    assert_eq!(seen, [(20, Some(Axis::Z), Multiplier::X100)]);
}

#[test]
fn a_stop_of_the_program_asks_for_the_loader_after_its_answer() {
    let mut r = Rig::new(true);
    assert!(!r.poll(0).enter_loader);
    // Operational: refused, and no reset.
    r.receive(1, 0x000, &[0x01, NODE]);
    let out = r.receive(
        2,
        0x600 + u16::from(NODE),
        &[0x2F, 0x51, 0x1F, 1, 0, 0, 0, 0],
    );
    assert!(!out.enter_loader);
    let abort = [0x80, 0x51, 0x1F, 1, 0x22, 0x00, 0x00, 0x08];
    assert_eq!(r.sent_on(0x580 + u16::from(NODE)), [abort.to_vec()]);
    // Pre-operational: the answer is in the transmit path when the round says "reset".
    r.receive(3, 0x000, &[0x80, NODE]);
    let out = r.receive(
        4,
        0x600 + u16::from(NODE),
        &[0x2F, 0x51, 0x1F, 1, 0, 0, 0, 0],
    );
    assert!(out.enter_loader);
    let answer = [0x60, 0x51, 0x1F, 1, 0, 0, 0, 0];
    assert_eq!(
        r.sent_on(0x580 + u16::from(NODE)).last(),
        Some(&answer.to_vec())
    );
    assert!(r.poll(5).enter_loader, "until the firmware resets");
}

/// The trial boot ends in one round, the first in which the device runs and a frame of it was
/// acknowledged: not while the controller waits for the bus, not before the acknowledgement,
/// never again after it.
#[test]
fn the_trial_is_confirmed_once_when_a_frame_of_the_running_node_is_acknowledged() {
    let mut r = Rig::new(false);
    r.port.acknowledged = true; // a stale flag: the node must still be running first
    for ms in 0..100 {
        assert!(!r.poll(ms).confirm_trial, "joining at {ms} ms");
    }
    r.port.bus_free = true;
    r.port.acknowledged = false;
    assert!(
        !r.poll(100).confirm_trial,
        "booted, the boot-up not acknowledged yet"
    );
    assert!(!r.poll(101).confirm_trial);
    r.port.acknowledged = true;
    assert!(r.poll(102).confirm_trial, "the boot-up acknowledged");
    let later: Vec<bool> = (103..200).map(|ms| r.poll(ms).confirm_trial).collect();
    assert!(later.iter().all(|&c| !c), "once");
}

/// A master's 0x1F51:1 = 0x80 confirms the image when no frame of it was acknowledged (a
/// master that confirms after the boot-up, as CiA 302-3 masters do), once.
#[test]
fn a_masters_confirm_ends_the_trial_without_an_acknowledgement() {
    let mut r = Rig::new(true);
    assert!(!r.poll(0).confirm_trial);
    let confirm = [0x2F, 0x51, 0x1F, 0x01, 0x80, 0, 0, 0];
    let out = r.receive(10, 0x600 + u16::from(NODE), &confirm);
    assert_eq!(
        r.sent_on(0x580 + u16::from(NODE)),
        [vec![0x60, 0x51, 0x1F, 0x01, 0, 0, 0, 0]]
    );
    assert!(
        out.confirm_trial,
        "confirmed in the round that took the write"
    );
    r.port.acknowledged = true;
    assert!(!r.poll(20).confirm_trial, "already confirmed");
}
