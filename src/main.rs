//! The RTIC 2 application: interrupt bindings, priorities and resources.
//!
//! | task | runs on | priority | shares |
//! |---|---|---|---|
//! | `wheel_edge` | EXTI9_5 (wheel A/B, both edges) | 4 | `wheel` |
//! | `can_rx0` | USB_LP_CAN_RX0 | 3 | `can` |
//! | `can_tx` | USB_HP_CAN_TX | 3 | `can` |
//! | `can_sce` | CAN_SCE | 3 | `can` |
//! | `canopen` | software (TIM3 dispatcher) | 2 | `wheel`, `can`, `status` |
//! | `selector` | software (TIM3 dispatcher) | 2 | `wheel` |
//! | `indicators` | software (TIM2 dispatcher) | 1 | `status` |
//! | `idle` | thread mode | 0 | - |
//!
//! The wheel's edges preempt everything: an edge is only known by the levels read after it,
//! so a late read merges two edges into an illegal jump. Nothing else is urgent on that scale.
//! The CAN interrupts come next because the receive FIFO holds only three frames and the
//! mailboxes only three; they only move frames between hardware and queues. Everything that
//! touches the CANopen device runs at one priority (2), so the device itself needs no lock
//! and its tasks never preempt one another. The LEDs come last.
//!
//! SysTick (the monotonic) keeps its reset priority, above all tasks: its handler is a
//! counter increment and a timer-queue check, and it must not miss a tick.
#![no_std]
#![no_main]

use defmt_rtt as _;

use handwheel_firmware::events::Events;
use rtic_monotonics::systick::prelude::*;

systick_monotonic!(Mono, 1_000);

defmt::timestamp!("{=u32:ms}", Mono::now().ticks());

/// Interrupt-to-`canopen` wake-ups.
static EVENTS: Events = Events::new();

#[rtic::app(device = stm32f1xx_hal::pac, dispatchers = [TIM2, TIM3])]
mod app {
    use super::{Mono, EVENTS};

    use defmt::{info, unwrap};
    use handwheel_core::{
        DecoderConfig, Handwheel, Selector, WheelAccess, DEFAULT_DEBOUNCE_SAMPLES,
    };
    use handwheel_firmware::{
        board::{self, Leds, Selectors, WheelInputs, SYSCLK_HZ},
        can::{self, CanPort, Mode, RxConsumer, RxProducer, RxQueue},
        clock::WideClock,
        events::EventSet,
        leds::{err_pattern, Pattern},
        node_config,
        storage::FlashStorage,
        supervision::Supervision,
        wheel::SharedWheel,
    };
    use rtic::Mutex;
    use rtic_monotonics::systick::prelude::*;
    use stm32f1xx_hal::watchdog::IndependentWatchdog;

    /// Selector sampling period (4 stable samples = 20 ms debounce).
    const SAMPLE_PERIOD_MS: u32 = 5;
    /// LED update period: a quarter of the 200 ms CiA 303-3 phase.
    const LED_PERIOD_MS: u32 = 50;
    /// The longest the CAN-side task sleeps, so that it feeds the watchdog in time.
    const MAX_SLEEP_MS: u32 = 100;
    /// Watchdog timeout: several missed rounds of the CAN-side task, longer than a flash
    /// page erase (up to 40 ms).
    const WATCHDOG_MS: u32 = 500;

    #[shared]
    struct Shared {
        /// Decoder and feed accumulator: written by every edge, read and configured by the
        /// CAN side.
        wheel: Handwheel,
        /// bxCAN and its transmit queue.
        can: CanPort,
        /// What the LEDs show.
        status: Status,
    }

    #[local]
    struct Local {
        wheel_inputs: WheelInputs,
        rx_producer: RxProducer,
        rx_consumer: RxConsumer,
        selectors: Selectors,
        selector: Selector,
        leds: Leds,
        watchdog: IndependentWatchdog,
        storage: FlashStorage,
    }

    /// Inputs of the indicator LEDs.
    #[derive(Clone, Copy)]
    pub struct Status {
        bus: can::bus::BusState,
        // INTEGRATION: the device's NMT state and error indication join here.
    }

    #[init(local = [rx_queue: RxQueue = RxQueue::new()])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let mut board = board::init(cx.device);
        Mono::start(cx.core.SYST, SYSCLK_HZ);

        let stored = board.storage.load();
        let (settings, source) =
            node_config::select(board.dip, stored.as_ref().map(|s| s.settings));
        let serial = handwheel_firmware::serial_number(board.unique_id);
        info!(
            "boot: node-ID {=u8}, {=u32} kbit/s ({}, DIP {=u8:#04x}), reset cause {}",
            settings.node_id,
            settings.bit_rate.kbit_per_second(),
            source,
            board.dip,
            board.reset_cause
        );
        info!(
            "serial number {=u32:#010x} (unique ID {=u32:08x}{=u32:08x}{=u32:08x})",
            serial, board.unique_id[2], board.unique_id[1], board.unique_id[0]
        );
        // INTEGRATION: `HandwheelDevice::new(node_id, serial, storage)` here, with
        // `settings.node_id`, `serial` (0x1018:4) and `board.storage` behind the engine's
        // `Storage` trait (blob = `Stored::blob`); it becomes a `device` resource shared by
        // `canopen`, `selector` and `indicators`.

        let can = can::start(board.can, settings.bit_rate, settings.node_id, Mode::Normal);
        let (rx_producer, rx_consumer) = cx.local.rx_queue.split();
        let wheel = Handwheel::new(DecoderConfig::default(), board.wheel.levels());
        let selector = unwrap!(Selector::new(DEFAULT_DEBOUNCE_SAMPLES));

        board.watchdog.start(WATCHDOG_MS.millis());
        unwrap!(canopen::spawn());
        unwrap!(selector::spawn());
        unwrap!(indicators::spawn());

        (
            Shared {
                wheel,
                can: CanPort::new(can),
                status: Status {
                    bus: can::bus::BusState::ErrorActive,
                },
            },
            Local {
                wheel_inputs: board.wheel,
                rx_producer,
                rx_consumer,
                selectors: board.selectors,
                selector,
                leds: board.leds,
                watchdog: board.watchdog,
                storage: board.storage,
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

    /// One wheel edge: acknowledge, read A and B in one port read, decode.
    ///
    /// The highest priority, so the wheel's lock is free here and nothing delays the read
    /// beyond SysTick. The CAN side's locks of `wheel` hold this task off for at most one
    /// short object access. It wakes `canopen` only when a detent (or a status change) makes
    /// a feed frame due.
    #[task(binds = EXTI9_5, priority = 4, local = [wheel_inputs], shared = [wheel])]
    fn wheel_edge(mut cx: wheel_edge::Context) {
        let levels = cx.local.wheel_inputs.acknowledge_edge();
        if cx.shared.wheel.lock(|wheel| wheel.on_edge(levels)) {
            EVENTS.raise(EventSet::FEED_DUE);
        }
    }

    /// Receive FIFO 0 has frames: move them to the receive queue for `canopen`.
    #[task(binds = USB_LP_CAN_RX0, priority = 3, local = [rx_producer], shared = [can])]
    fn can_rx0(mut cx: can_rx0::Context) {
        let lost = cx
            .shared
            .can
            .lock(|can| can.drain_fifo0(cx.local.rx_producer));
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
        cx.shared.can.lock(|can| can.on_mailbox_empty());
    }

    /// Warning limit, error passive or bus-off was reached: let `canopen` look.
    #[task(binds = CAN_SCE, priority = 3, shared = [can])]
    fn can_sce(mut cx: can_sce::Context) {
        cx.shared.can.lock(|can| can.on_status_change());
        EVENTS.raise(EventSet::BUS_STATUS);
    }

    /// The CAN side: everything that touches the CANopen device, in one loop at one priority.
    ///
    /// Each round feeds the watchdog, so if this loop stops (a hung lock, a dead executor),
    /// the MCU resets. It sleeps until an interrupt raises an event or the next deadline.
    #[task(
        priority = 2,
        local = [
            rx_consumer,
            watchdog,
            storage,
            supervision: Supervision = Supervision::new(),
            clock: WideClock = WideClock::new(),
        ],
        shared = [wheel, can, status]
    )]
    async fn canopen(mut cx: canopen::Context) {
        // INTEGRATION: device.start(Instant::from_micros(now), &mut SharedWheel(&mut
        // cx.shared.wheel), &mut can::TxSink(&mut cx.shared.can)), `now` from
        // `cx.local.clock`; `TxSink` implements the engine's `FrameSink` through
        // `Frame::new(f.id(), f.data())`. `cx.local.storage` moves into the device.
        let mut frames: u32 = 0;
        loop {
            cx.local.watchdog.feed();
            let wake_at = wake_time(cx.local.supervision);
            let events = match Mono::timeout_at(wake_at, EVENTS.wait()).await {
                Ok(events) => events,
                Err(_timeout) => EVENTS.take(),
            };
            let _now = cx.local.clock.now_us(Mono::now().ticks());

            while let Some(_frame) = cx.local.rx_consumer.dequeue() {
                frames = frames.wrapping_add(1);
                // INTEGRATION: device.on_frame(_now, &_frame, &mut wheel, &mut tx_sink);
            }
            if events.contains(EventSet::FEED_DUE) {
                // INTEGRATION: device.feed_changed();
            }
            supervise(&mut cx, frames);
            // INTEGRATION: device.poll(_now, &mut wheel, &mut tx_sink);
        }
    }

    /// Bus state, lost frames and encoder errors: log them and publish the bus state.
    fn supervise(cx: &mut canopen::Context, frames: u32) {
        let supervision = &mut *cx.local.supervision;
        if let Some(_event) = supervision.check_bus() {
            // INTEGRATION: EMCY through device.engine() per `_event` (0x8120 raise on
            // ErrorPassive, clear on ErrorActiveAgain; 0x8140 on BusOffRecovered).
        }
        let stats = cx.shared.can.lock(|can| can.stats());
        if supervision.check_rx_overruns(stats.rx_overruns) {
            // INTEGRATION: EMCY 0x8110 through device.engine() (bus::EMCY_CAN_OVERRUN).
        }
        let illegal =
            SharedWheel(&mut cx.shared.wheel).with_wheel(|w| w.decoder.illegal_transitions());
        supervision.check_encoder(illegal);
        let bus = supervision.bus_state();
        cx.shared.status.lock(|status| status.bus = bus);
        defmt::trace!("canopen round: {=u32} frames so far, {}", frames, stats);
    }

    /// When `canopen` must run next even without an event.
    fn wake_time(supervision: &Supervision) -> <Mono as Monotonic>::Instant {
        // While the controller is not error-active, poll for its recovery (no interrupt
        // announces it).
        let sleep_ms = match supervision.bus_state() {
            can::bus::BusState::ErrorActive => MAX_SLEEP_MS,
            _ => can::bus::RECOVERY_POLL_MS,
        };
        // INTEGRATION: the earlier of this and `device.next_deadline()`, converted with
        // `clock::deadline_tick(t.as_micros())` into `Instant::from_ticks(..)`.
        Mono::now() + sleep_ms.millis()
    }

    /// Samples the axis and multiplier switches every 5 ms; a debounced change goes to the
    /// feed accumulator (a new epoch, a feed frame due).
    #[task(priority = 2, local = [selectors, selector], shared = [wheel])]
    async fn selector(mut cx: selector::Context) {
        let mut next = Mono::now();
        loop {
            let Ok((axis, multiplier)) = cx.local.selectors.read();
            if let Some(selection) = cx.local.selector.sample(axis, multiplier) {
                info!(
                    "selection: axis {=u8}, x{=u8}",
                    handwheel_core::Axis::option_value(selection.axis),
                    selection.multiplier.factor()
                );
                // INTEGRATION: device.set_selection(selection, &mut wheel) instead.
                if cx.shared.wheel.lock(|w| w.feed.set_selection(selection)) {
                    EVENTS.raise(EventSet::FEED_DUE | EventSet::SELECTION);
                }
            }
            next += SAMPLE_PERIOD_MS.millis();
            Mono::delay_until(next).await;
        }
    }

    /// RUN and ERR LEDs (CiA 303-3), updated every 50 ms.
    #[task(priority = 1, local = [leds], shared = [status])]
    async fn indicators(mut cx: indicators::Context) {
        let mut next = Mono::now();
        loop {
            let now_ms = Mono::now().ticks();
            let status = cx.shared.status.lock(|status| *status);
            // INTEGRATION: (run, err) = canopen_slave::indicators(device.nmt_state(),
            // max(device.error_indication(), bus error), now_ms). Until then RUN blinks
            // (not operational) and ERR shows the controller's error state.
            let run = Pattern::Blinking.is_on(now_ms);
            let err = err_pattern(status.bus).is_on(now_ms);
            cx.local.leds.set(run, err);
            next += LED_PERIOD_MS.millis();
            Mono::delay_until(next).await;
        }
    }
}
