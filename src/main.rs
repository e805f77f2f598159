//! The RTIC 2 application: interrupt bindings, priorities and resources.
//!
//! | task | runs on | priority | shares |
//! |---|---|---|---|
//! | `wheel_edge` | EXTI9_5 (wheel A/B, both edges) | 16 | `wheel` |
//! | `feed_due` | TIM2 vector, pended by `wheel_edge` | 3 | - |
//! | `can_rx0` | USB_LP_CAN_RX0 | 3 | `can` |
//! | `can_tx` | USB_HP_CAN_TX | 3 | `can` |
//! | `can_sce` | CAN_SCE | 3 | `can` |
//! | SysTick (the monotonic) | SysTick | 3 | its timer queue, in critical sections |
//! | `canopen` | software (TIM3 dispatcher) | 2 | `can`, `wheel` |
//! | `idle` | thread mode | 0 | - |
//!
//! The wheel's edges preempt every task: an edge is only known by the levels read after it,
//! so a late read merges two edges into an illegal jump. `wheel_edge` runs at the highest
//! priority the part has (16, NVIC priority 0), owns the pins (a local resource) and shares
//! the decoder with the CAN side (`wheel`, `handwheel_core::EdgeState`): RTIC guarantees the
//! exclusive access. At that ceiling RTIC's lock is the critical section (PRIMASK), the
//! cheapest lock for the edge itself; the CAN side takes it for a copy of the totals or a
//! decoder command, a few dozen cycles. What else holds the edge off is that same critical
//! section, which stm32f1xx-hal brings (cortex-m's single-core one): defmt's RTT logger
//! holds it for a log frame, the monotonic's timer queue and the wakers for a few
//! instructions; see docs/PERFORMANCE.md for the longest stretch. The edge never wakes the
//! CAN side itself: a detent pends `feed_due` (one NVIC store), which raises the wake-up
//! below it.
//! The CAN interrupts come next because the receive FIFO holds only three frames and the
//! mailboxes only three; they only move frames between hardware and queues. Everything that
//! touches the CANopen device runs in one task, `canopen` (priority 2), which also samples
//! the selector switches and drives the LEDs and the digital outputs: the device and the accumulator are that task's
//! own and need no lock, and nothing on the CAN side ever preempts another part of it.
//!
//! SysTick (the monotonic) runs at priority 3, not at its reset priority above everything:
//! so it never delays an edge. A tick is a counter increment and a queue check; it waits at
//! most for one CAN interrupt, the edge or a critical section, far less than its 1 ms
//! period, so no tick is missed.
#![no_std]
#![no_main]

use defmt_rtt as _;

use handwheel_firmware::events::Events;
use rtic_monotonics::systick::prelude::*;

systick_monotonic!(Mono, 1_000);

defmt::timestamp!("{=u32:ms}", Mono::now().ticks());

/// Interrupt-to-`canopen` wake-ups.
static EVENTS: Events = Events::new();

#[rtic::app(device = handwheel_firmware::pac, dispatchers = [TIM3])]
mod app {
    use super::{Mono, EVENTS};

    use board::{DeviceStorage, DigitalOutputs, Leds, Selectors, WheelInputs, SYSCLK_HZ};
    use cortex_m::peripheral::scb::SystemHandler;
    use defmt::info;
    use handwheel_core::{DecoderConfig, EdgeState, LinkedWheel};
    use handwheel_device::{CanIo, HandwheelDevice, Node};
    use handwheel_firmware::{
        board,
        can::{self, CanPort, CanSide, Mode, RxConsumer, RxProducer, RxQueue},
        edge,
        events::EventSet,
        handoff, image_header, node_config, priority, round_log,
    };
    use rtic_monotonics::systick::prelude::*;

    // The literals of the task attributes below and the levels the firmware programs itself
    // (`priority`) must agree: the edge at the top, SysTick at the CAN side.
    const _: () = assert!(priority::WHEEL == 16 && priority::CAN == 3);

    /// Watchdog timeout: several missed rounds of the CAN-side task (which sleeps at most
    /// `duties::MAX_SLEEP_MS`), longer than a flash page erase (up to 40 ms).
    const WATCHDOG_MS: u32 = 500;

    /// How long the transmit path may take to drain before the reset into the loader, in
    /// milliseconds: the SDO answer and what waits before it (a heartbeat, an EMCY; the feed
    /// is off), each frame at most 135 bits, 13.5 ms at the slowest rate (10 kbit/s), well
    /// under 1 ms at 125 kbit/s and up. Bounded: a bus that takes nothing must not keep the
    /// node out of the loader.
    const LOADER_DRAIN_MS: u32 = 50;

    /// The CANopen handwheel with its parameter page, as the step function `canopen` runs.
    type HandwheelNode = Node<DeviceStorage>;

    #[shared]
    struct Shared {
        /// bxCAN and its transmit queue.
        can: CanPort,
        /// The decoder and its totals: written by every edge, read and configured by the
        /// CAN side under its lock.
        wheel: EdgeState,
    }

    #[local]
    struct Local {
        /// The wheel's A/B inputs: only `wheel_edge` reads them.
        wheel_inputs: WheelInputs,
        /// The CANopen device and the decisions around it: only `canopen` touches it.
        node: HandwheelNode,
        rx_producer: RxProducer,
        rx_consumer: RxConsumer,
        selectors: Selectors,
        leds: Leds,
        outputs: DigitalOutputs,
        watchdog: board::Watchdog,
    }

    #[init(local = [rx_queue: RxQueue = RxQueue::new()])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let mut core = cx.core;
        let mut board = board::init(cx.device);
        Mono::start(core.SYST, SYSCLK_HZ);
        // SAFETY: no RTIC lock depends on SysTick's level, as it is no RTIC task; at the CAN
        // side's level it never delays the wheel's edge task (see the table above).
        unsafe {
            core.SCB
                .set_priority(SystemHandler::SysTick, priority::hardware(priority::CAN))
        };

        let mut page = DeviceStorage::new(board.storage);
        let stored = page.stored().map(|(settings, _)| settings);
        let (settings, source) = node_config::select(board.dip, stored);
        page.set_settings(settings);
        let serial = node_config::serial_number(board.unique_id);
        info!(
            "boot: node-ID {=u8}, {=u32} kbit/s ({}, DIP {=u8:#04x}), reset cause {}, \
             serial number {=u32:#010x}",
            settings.node_id_byte(),
            settings.bit_rate.kbit_per_second(),
            source,
            board.dip,
            board.reset_cause,
            serial
        );
        // `node_config` yields node-IDs 1..=127, or 0xFF stored by LSS: unconfigured (`None`),
        // the device then answers LSS only.
        let node_id = settings.node_id;
        let device = HandwheelDevice::with_settings(node_id, settings.bit_rate, serial, page)
            .with_software_id(image_header::own_crc());
        let node = Node::new(device, settings.bit_rate);

        // The defaults' filter; `canopen` reprograms it once the device has loaded stored
        // parameters (a stored 0x1005) and whenever a master moves an identifier. Asks the
        // controller to join and returns at once: on a dominant bus it never would (the node
        // waits for it, the loop feeding the watchdog started below).
        let can = can::start(board.can, settings.bit_rate, node.rx_filter(), Mode::Normal);
        let (rx_producer, rx_consumer) = cx.local.rx_queue.split();
        // The decoder at rest on the levels read now, with the settings 0x2020 starts with.
        let wheel = EdgeState::new(DecoderConfig::default(), board.wheel.levels());

        board.watchdog.start(WATCHDOG_MS);
        // The first spawn of a task cannot fail. Were it ever to, nothing would feed the
        // watchdog started above, and the MCU would reset.
        let _ = canopen::spawn();

        (
            Shared {
                can: CanPort::new(can),
                wheel,
            },
            Local {
                wheel_inputs: board.wheel,
                node,
                rx_producer,
                rx_consumer,
                selectors: board.selectors,
                leds: board.leds,
                outputs: board.outputs,
                watchdog: board.watchdog,
            },
        )
    }

    /// Busy idle, no WFI: a sleeping STM32F103 drops the debug connection, and with it
    /// probe-rs' RTT log, unless DBGMCU keeps the clocks on in sleep.
    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            core::hint::spin_loop();
        }
    }

    /// One wheel edge: acknowledge, read A and B in one port read, decode under the `wheel`
    /// lock (at this ceiling the critical section, a few cycles) and, after a detent, pend
    /// `feed_due` before leaving it. No log, no panic path, no wake-up.
    #[task(binds = EXTI9_5, priority = 16, local = [wheel_inputs], shared = [wheel])]
    fn wheel_edge(mut cx: wheel_edge::Context) {
        let levels = cx.local.wheel_inputs.acknowledge_edge();
        cx.shared.wheel.lock(|wheel| {
            if wheel.on_edge(levels) {
                rtic::pend(edge::FEED_DUE);
            }
        });
    }

    /// Wakes `canopen` for a feed frame. Runs on TIM2's vector (the timer itself is unused),
    /// pended by `wheel_edge`, which thus costs one NVIC store instead of a wake-up (a
    /// critical section on every detent); below the wheel's priority, so an edge preempts
    /// it, and above `canopen`'s, so the wake-up is immediate. Several edges before it runs
    /// cost one wake.
    #[task(binds = TIM2, priority = 3)]
    fn feed_due(_: feed_due::Context) {
        EVENTS.raise(EventSet::FEED_DUE);
    }

    /// Receive FIFO 0 has frames: move them to the receive queue for `canopen`.
    #[task(binds = USB_LP_CAN_RX0, priority = 3, local = [rx_producer], shared = [can])]
    fn can_rx0(mut cx: can_rx0::Context) {
        let lost = cx
            .shared
            .can
            .lock(|can| can.on_receive(cx.local.rx_producer));
        let overrun = if lost {
            EventSet::RX_OVERRUN
        } else {
            EventSet::empty()
        };
        EVENTS.raise(EventSet::FRAMES | overrun);
    }

    /// A transmit mailbox became free: refill it from the queue.
    #[task(binds = USB_HP_CAN_TX, priority = 3, shared = [can])]
    fn can_tx(mut cx: can_tx::Context) {
        cx.shared.can.lock(|can| can.on_transmit_room());
    }

    /// Warning limit, error passive or bus-off was reached: let `canopen` look.
    #[task(binds = CAN_SCE, priority = 3, shared = [can])]
    fn can_sce(mut cx: can_sce::Context) {
        cx.shared.can.lock(|can| can.on_status_change());
        EVENTS.raise(EventSet::BUS_STATUS);
    }

    /// The CAN side: everything that touches the CANopen device, in one loop at one priority.
    ///
    /// A loop of I/O around the step function (`handwheel_device::Node::poll`, which decides
    /// everything: joining the bus at power-on, the switches, the device, the bus state, a
    /// bit-rate switch, the filter, the LEDs and how long to sleep). Each round feeds the
    /// watchdog, so if this loop stops (a hung lock, a dead executor), the MCU resets. It
    /// sleeps until an interrupt raises an event or the node's sleep is over.
    /// Sampling the switches and driving the LEDs here rather than in tasks of their own
    /// costs nothing in latency (they are 5 and 50 ms periodic, far slower than a round) and
    /// saves a second async task, its timer-queue entry and a dispatcher interrupt. The
    /// decoder it shares with `wheel_edge` is reached under the `wheel` lock, a copy or a
    /// command at a time; the CAN port through one short lock per call, never for a round.
    #[task(
        priority = 2,
        local = [node, rx_consumer, watchdog, selectors, leds, outputs],
        shared = [can, wheel]
    )]
    async fn canopen(cx: canopen::Context) {
        #[cfg(feature = "stack-overflow-test")]
        handwheel_firmware::overflow::run();
        let local = cx.local;
        let mut can = CanSide::new(local.rx_consumer, cx.shared.can, || Mono::now().ticks());
        let wheel = &mut LinkedWheel::new(cx.shared.wheel, DecoderConfig::default());
        loop {
            local.watchdog.feed();
            let ticks = Mono::now().ticks();
            let out = local.node.poll(ticks, &mut can, local.selectors, wheel);
            if let Some((run, err)) = out.leds {
                local.leds.set(run, err);
            }
            // Every round, so that an error reaction reaches the pins in the round that found
            // the error.
            local.outputs.set(out.digital.jog_live, out.digital.written);
            // A frame on a new identifier is received from the next round on; before that it
            // is dropped, as by any controller before its reconfiguration.
            if let Some(filter) = out.rx_filter {
                defmt::debug!(
                    "CAN filter: SYNC {=u16:#05x}, SDO {=u16:#05x} and {=u16:#05x}, RPDO {=u16:#05x}",
                    filter.sync(),
                    filter.sdo_request(),
                    filter.second_sdo_request(),
                    filter.rpdo()
                );
                can.set_rx_filter(filter);
            }
            round_log::print(&out.log, can.counters);
            // The loader started this image on trial (docs/FIRMWARE-UPDATE.md, "Trial boot");
            // the node says when it is healthy on the bus.
            if out.confirm_trial {
                handoff::confirm_start();
                info!("trial boot: confirmed, healthy on the bus");
            }
            if out.enter_loader {
                // 0x1F51:1 = 0 was answered: let that answer reach the bus (a bounded wait,
                // `LOADER_DRAIN_MS`), then reset into the loader, which stays
                // (docs/FIRMWARE-UPDATE.md).
                // A spin, not a sleep: nothing else of this task is left to do, and the CAN
                // interrupts that drain the path and SysTick preempt it.
                let start = Mono::now().ticks();
                while can.transmit_state().waiting
                    && Mono::now().ticks().wrapping_sub(start) < LOADER_DRAIN_MS
                {}
                info!("program control: stop, resetting into the loader");
                handoff::reset_into_loader();
            }
            // Whatever wakes the round (frames, the bus, the edge's `FEED_DUE`), the node
            // looks at everything.
            let wake_at =
                <Mono as Monotonic>::Instant::from_ticks(ticks.wrapping_add(out.sleep_ms));
            if Mono::timeout_at(wake_at, EVENTS.wait()).await.is_err() {
                EVENTS.take();
            }
        }
    }
}
