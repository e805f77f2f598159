//! The handwheel's resident loader: the first image in flash (pages 0-11), never overwritten
//! by an update (docs/FIRMWARE-UPDATE.md).
//!
//! At every reset it reads the two `HANDOFF` words first (`canopen_loader::boot`): the
//! application's request to stay (its 0x1F51 "stop"), or the count of the application's
//! starts that it has not confirmed. It stays when asked, when the slot holds no valid
//! application (mark, header, vector table, CRC: `canopen_loader::valid_application`), or
//! when the application was started `MAX_TRIAL_STARTS` times in a row without confirming
//! (0x1F57 code 64). Otherwise it listens on the bus for `LISTEN_MS`, silent: a master's
//! 0x1F51:1 = 0 to this node in that window keeps it (the way back from an application that
//! never talks, at every power-on). Nobody asked: it counts the start in `HANDOFF`, puts
//! every peripheral it used back into its reset state, and starts the application (VTOR,
//! MSP, reset vector) under the running watchdog. Staying, it is a minimal CANopen node
//! (`canopen_loader::LoaderNode`) at the application's node-ID and bit rate, which takes a
//! new image by CiA 302-3 program download, in a polled loop: no interrupts, no RTIC. Its
//! defmt log (RTT) says why it stays.
//!
//! Watchdog: the loader starts the IWDG (2 s nominal, at least 1.3 s with the LSI's
//! spread) and feeds it in its loop and around every page erase, so that a loader stuck by a
//! fault resets into the boot decision again. It cannot be stopped, so the application
//! starts with it running: an application that hangs, faults or locks up before it feeds
//! the watchdog is reset within 2 s, and its start counts as unconfirmed.
#![no_std]
#![no_main]

use defmt_rtt as _;

mod bus;
mod flash;

use canopen_loader::boot::{LISTEN_MS, MAX_TRIAL_STARTS};
use canopen_loader::layout::{APP_ORIGIN, HANDOFF_ORIGIN};
use canopen_loader::program::Control;
use canopen_loader::{
    is_rescue_request, valid_application, Boot, BootRecord, DeviceId, FlashStatus, LoaderConfig,
    LoaderNode, Request, StayReason,
};
use canopen_slave::{FrameSink, Instant, NodeId};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};
use cortex_m_rt::entry;
use handwheel_board::clocks::SYSCLK_HZ;
use handwheel_board::watchdog::Watchdog;
use handwheel_storage::node_config;
use handwheel_storage::page::ParameterPage;
use stm32f1xx_hal::{pac, prelude::*};

/// The application this loader takes images for (0x1018:1 and :2 of the application).
const DEVICE: DeviceId = canopen_loader::header::PRODUCT;
/// 0x1018:3 of the loader.
const REVISION: u32 = 1;
/// The node-ID when the stored settings say "unconfigured" (LSS, 0xFF): the loader has no
/// LSS slave to be given one, so it answers at the factory node-ID.
const UNCONFIGURED_NODE_ID: u8 = 16;
/// The watchdog's nominal timeout.
const WATCHDOG_MS: u32 = 2000;
/// How long a reset waits for the frames queued before it (the answer to "start").
const FLUSH_US: u64 = 50_000;

#[entry]
fn main() -> ! {
    let boot = Boot::decide(read_record(), || {
        valid_application(&flash::MAPPED_SLOT, DEVICE).is_some()
    });
    write_record(boot.record_kept());
    run(boot)
}

/// The boot record in the two `HANDOFF` words.
fn read_record() -> BootRecord {
    let at = HANDOFF_ORIGIN as *const u32;
    // SAFETY: HANDOFF is two word-aligned words of SRAM (memory.x) outside every image's
    // RAM region, so no Rust object lives there; nothing else runs (no interrupts).
    let words = unsafe { [at.read_volatile(), at.add(1).read_volatile()] };
    BootRecord::decode(words)
}

/// Writes `record` into the two `HANDOFF` words, where the next reset finds it.
fn write_record(record: BootRecord) {
    let at = HANDOFF_ORIGIN as *mut u32;
    let [first, second] = record.encode();
    // SAFETY: as in `read_record`: SRAM no Rust object occupies; volatile, so that the
    // stores happen before the jump or reset that follows.
    unsafe {
        at.write_volatile(first);
        at.add(1).write_volatile(second);
    }
}

/// Starts the application: its vector table for VTOR, its stack pointer, its reset vector.
///
/// # Safety
///
/// The slot must hold a valid application (`valid_application`), and every peripheral the
/// application's start-up expects in its reset state must be in it (`release_peripherals`).
unsafe fn start_application() -> ! {
    // SAFETY: VTOR takes a 512-byte aligned address in code memory (APP_ORIGIN is: asserted
    // in canopen_loader::layout); `bootload` loads MSP and jumps to the reset vector of the table at
    // APP_ORIGIN, which the caller checked; nothing of the loader runs after it.
    unsafe {
        (*SCB::PTR).vtor.write(APP_ORIGIN);
        cortex_m::asm::bootload(APP_ORIGIN as *const u32)
    }
}

/// Puts back into their reset state what the loader set up for its window, so that the
/// application starts as from a reset (its start-up assumes it): bxCAN, GPIOB and AFIO
/// through their reset bits, their clocks off, SYSCLK back on the HSI with PLL and HSE off,
/// the flash's wait states and SysTick as out of reset. The watchdog keeps running (it
/// cannot be stopped): it is the trial's.
///
/// Register glue: the HAL has no way back from `freeze` or from a peripheral it enabled.
fn release_peripherals() {
    // SAFETY: called once, right before the jump, after the loader's last use of its HAL
    // handles (none is used again: the jump does not return) and with no interrupt enabled;
    // each write sets a register to its documented reset value (RM0008 7.3: the RCC's;
    // 3.3.3: FLASH_ACR; PM0056 4.5: SysTick), in the safe order: SYSCLK switched to the HSI
    // and the switch seen before PLL and HSE go off, the wait states lowered only once the
    // clock is the slow one.
    unsafe {
        let rcc = &*pac::RCC::ptr();
        rcc.apb1rstr().write(|w| w.canrst().set_bit());
        rcc.apb2rstr()
            .write(|w| w.iopbrst().set_bit().afiorst().set_bit());
        rcc.apb1rstr().reset();
        rcc.apb2rstr().reset();
        rcc.apb1enr().reset();
        rcc.apb2enr().reset();
        rcc.cfgr().modify(|_, w| w.sw().hsi());
        while !rcc.cfgr().read().sws().is_hsi() {}
        rcc.cfgr().reset();
        rcc.cr()
            .modify(|_, w| w.pllon().clear_bit().hseon().clear_bit());
        while rcc.cr().read().pllrdy().bit_is_set() {}
        (*pac::FLASH::ptr()).acr().reset();
        let syst = &*SYST::PTR;
        syst.csr.write(0);
        syst.rvr.write(0);
        syst.cvr.write(0);
    }
}

/// The loader's clock: SysTick at the core clock as a free-running 24-bit down counter,
/// extended to microseconds. It wraps every 233 ms; the loop reads it far more often (its
/// longest step is a page erase, 40 ms, or a CRC over the slot, about 40 ms).
struct Clock {
    last: u32,
    us: u64,
    /// Cycles not yet counted as a whole microsecond.
    rest: u32,
}

impl Clock {
    const CYCLES_PER_US: u32 = SYSCLK_HZ / 1_000_000;

    fn start(mut syst: SYST) -> Self {
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(0x00FF_FFFF);
        syst.clear_current();
        syst.enable_counter();
        Self {
            last: SYST::get_current(),
            us: 0,
            rest: 0,
        }
    }

    fn now(&mut self) -> Instant {
        let current = SYST::get_current();
        // A down counter: the cycles since the last read, modulo its 24 bits.
        let cycles = (self.last.wrapping_sub(current) & 0x00FF_FFFF) + self.rest;
        self.last = current;
        self.us += u64::from(cycles / Self::CYCLES_PER_US);
        self.rest = cycles % Self::CYCLES_PER_US;
        Instant::from_micros(self.us)
    }
}

/// The loader on the bus: for `boot`'s listening window, then (unless it starts the
/// application) as a CANopen node for good (it leaves by a system reset).
fn run(boot: Boot) -> ! {
    let (Some(dp), Some(cp)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
        SCB::sys_reset()
    };
    let mut flash = dp.FLASH.constrain();
    // The board's clocks, the application's (handwheel_board::clocks).
    let mut rcc = handwheel_board::clocks::freeze(dp.RCC, &mut flash.acr);
    let mut watchdog = Watchdog::new(dp.IWDG, &dp.DBGMCU);
    watchdog.start(WATCHDOG_MS);

    let mut afio = dp.AFIO.constrain(&mut rcc);
    let mut gpiob = dp.GPIOB.split(&mut rcc);
    // The DIP switch and bxCAN's pins as the application has them (handwheel_board::pins).
    let dip = handwheel_board::read_dip_switch!(gpiob);
    let can = handwheel_board::open_can!(dp, afio, gpiob, rcc);

    // Node-ID and bit rate exactly as the application chooses them.
    let stored = ParameterPage::new(flash::PARAMETER_PAGES)
        .stored()
        .map(|(settings, _)| settings);
    let (settings, _source) = node_config::select(dip, stored);
    let node_id = settings
        .node_id
        .or(NodeId::new(UNCONFIGURED_NODE_ID).ok())
        .unwrap_or_else(|| SCB::sys_reset());
    let serial = node_config::serial_number(handwheel_board::chip::unique_id());

    let mut can = bus::start(can, settings.bit_rate, node_id);
    let mut slot = flash::Fpec::new(flash, watchdog);
    let mut clock = Clock::start(cp.SYST);
    let rescue = match boot {
        Boot::Listen { starts } => {
            let Some(request) = listen(&mut can, &mut clock, &mut slot.watchdog, node_id) else {
                write_record(Boot::record_at_start(starts));
                slot.watchdog.feed();
                release_peripherals();
                // SAFETY: `Boot::decide` found the application valid at this reset, and
                // nothing wrote the flash since; `release_peripherals` ran.
                unsafe { start_application() }
            };
            defmt::info!("loader: staying, a master asked in the listening window (0x1F51:1 = 0)");
            Some(request)
        }
        Boot::Stay(StayReason::Requested) => {
            defmt::info!("loader: staying, the application asked (0x1F51:1 = 0)");
            None
        }
        Boot::Stay(StayReason::NoValidProgram) => {
            defmt::info!("loader: staying, no valid application (0x1F57 code 1)");
            None
        }
        Boot::Stay(StayReason::TrialFailed) => {
            defmt::warn!(
                "loader: staying, the application was started {=u8} times and never confirmed: \
                 it hangs, faults or locks up before it is healthy on the bus (0x1F57 code 64)",
                MAX_TRIAL_STARTS
            );
            None
        }
    };
    let mut queue = bus::TxQueue::new();
    let config = LoaderConfig::new(node_id, DEVICE, REVISION, serial);
    let mut node = LoaderNode::new(config, &slot);
    if boot == Boot::Stay(StayReason::TrialFailed) {
        node.report_failed_trial();
    }
    node.start(clock.now(), &mut queue);
    // The request that kept the loader is answered as the node's first SDO request, once
    // the boot-up has left (the answer's identifier would pass it in the mailboxes).
    if rescue.is_some() {
        flush(&mut can, &mut queue, &mut clock);
    }
    let mut pending = rescue;

    loop {
        slot.watchdog.feed();
        let now = clock.now();
        let mut received = false;
        while let Some(frame) = pending.take().or_else(|| bus::receive(&mut can)) {
            received = true;
            if node.on_frame(now, &frame, &mut slot, &mut queue) == Some(Request::Reset) {
                let program = node.program();
                if program.control() == Control::Started
                    || program.status() != FlashStatus::TrialFailed
                {
                    // "Start", or the application that failed its trial was cleared: the
                    // next start is a fresh trial. Otherwise (a reset node) the failed
                    // trial keeps the loader.
                    write_record(BootRecord::Fresh);
                }
                reset_after(&mut can, &mut queue, &mut clock);
            }
        }
        node.poll(clock.now(), &mut queue);
        bus::transmit(&mut can, &mut queue);
        if !received {
            // YIELD: a no-op on the Cortex-M3, and the hint that this loop only waits, which
            // the emulated board takes to let time pass (tools/board-emu/server.py, `idle`).
            core::hint::spin_loop();
        }
    }
}

/// The listening window before a start of the application: `LISTEN_MS` of receiving,
/// sending nothing. Returns the request that keeps the loader (`is_rescue_request`), or
/// `None` when the window passed without one.
fn listen(
    can: &mut bus::Bxcan,
    clock: &mut Clock,
    watchdog: &mut Watchdog,
    node: NodeId,
) -> Option<canopen_slave::Frame> {
    let until = clock.now().add_millis(u64::from(LISTEN_MS));
    while clock.now() < until {
        watchdog.feed();
        match bus::receive(can) {
            Some(frame) if is_rescue_request(&frame, node) => return Some(frame),
            Some(_) => {}
            // YIELD: nothing to do until a frame or the window's end (the emulated board
            // lets time pass).
            None => core::hint::spin_loop(),
        }
    }
    None
}

/// Sends what is queued, for at most [`FLUSH_US`]; what did not go is dropped.
fn flush(can: &mut bus::Bxcan, queue: &mut bus::TxQueue, clock: &mut Clock) {
    let until = clock.now().add_micros(FLUSH_US);
    while (!queue.is_empty() || !can.is_transmitter_idle()) && clock.now() < until {
        bus::transmit(can, queue);
    }
    queue.discard_pending();
}

/// Sends what is queued (the answer to "start", `flush`), then resets: the boot decision
/// runs again.
fn reset_after(can: &mut bus::Bxcan, queue: &mut bus::TxQueue, clock: &mut Clock) -> ! {
    flush(can, queue, clock);
    SCB::sys_reset()
}

/// A panic resets: the boot decision again, and the loader if there is no application.
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    SCB::sys_reset()
}
