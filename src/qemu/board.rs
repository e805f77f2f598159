//! The QEMU board (`-M stm32vldiscovery`): what `init` sets up, and the stand-ins for the
//! hardware the emulator does not model. Same names as the STM32F103 board module, so the
//! RTIC application uses either unchanged.

use crate::pac;
use handwheel_core::AbLevels;
use handwheel_device::page::{ParameterPage, PAGES, PAGE_SIZE};

use super::{
    sim,
    slcan_port::{self, RxBytes, SlcanLink, SlcanReceiver},
    stimulus::StimulusLink,
    storage::RamStorage,
    usart::Usart,
};

pub use slcan_port::start as start_can;

/// The QEMU variant's CAN port: the shared queue and statistics over the SLCAN link.
pub type CanPort = crate::can::port::CanPort<slcan_port::Controller>;
/// The CANopen engine's storage: the parameter page over RAM.
pub type DeviceStorage = ParameterPage<RamStorage>;

/// Core clock, also the SysTick clock: QEMU's SysTick counts at 24 MHz whatever RCC is set
/// to, so the monotonic must be started with this rate for real-time milliseconds.
pub const SYSCLK_HZ: u32 = 24_000_000;

/// How long after power-on the `canopen` task waits before starting the CANopen device,
/// whose first act is the boot-up frame. QEMU starts the CPU when the master connects, and
/// the SLCAN channel is open from power-on, so without a wait the boot-up goes out some 6 ms
/// after the connection. pyserial's `socket://` open discards what is already in the socket
/// just after connecting; a master that is descheduled for those few ms in between (seen in
/// about 1 of 150 connections on a busy 2-core machine) loses the boot-up. The wait makes
/// that margin 100 ms longer. Bytes from the host meanwhile are received and answered (USART1
/// is enabled in `init`), and its frames wait in the receive queue.
pub const BOOT_UP_DELAY_MS: u32 = 100;

/// USART1 carrying the CAN link (SLCAN), the QEMU stand-in for the bxCAN instance.
pub type CanInstance = SlcanLink;

/// A fixed "unique ID" (ASCII `QEMU`): the emulator has no factory-programmed one.
const UNIQUE_ID: [u32; 3] = [u32::from_le_bytes(*b"QEMU"), 0, 0];

/// The QEMU board's parts: the simulated wheel, switches and LEDs, SLCAN on USART1,
/// parameters in RAM, a watchdog stand-in; the DIP switch reads all off, so the stored
/// (never, in RAM) or default node-ID 16 applies.
pub enum Parts {}

/// The USART lines' halves that the app's QEMU tasks own: the SLCAN receiver (USART1) and
/// the stimulus line (USART2).
pub struct Own {
    /// USART1's receiving half, for the task bound to USART1.
    pub slcan: SlcanReceiver,
    /// USART2, for the task bound to USART2.
    pub stimulus: StimulusLink,
}

crate::parts::board_parts!(
    Parts: WheelInputs, Selectors, Leds, CanInstance, RamStorage, watchdog::Watchdog, ResetCause, Own
);

/// Everything `init` sets up for the application.
pub type Board = crate::parts::Board<Parts>;

/// Sets the clock to HSI only and enables both USARTs with their receive interrupts (the
/// app's QEMU tasks are bound to them, and RTIC unmasks them after `init`). Takes the device
/// peripherals that RTIC's `init` hands over; runs with interrupts disabled (RTIC's `init`).
pub fn init(dp: pac::Peripherals) -> Board {
    // The reset clock (HSI, no PLL) stays: nothing to set up, and waiting for HSE or PLL
    // ready would hang (QEMU's RCC is a stub that reads 0). SysTick runs at `SYSCLK_HZ` in
    // QEMU.

    // Both USARTs at once: QEMU drops bytes that arrive before UE and RE are set.
    // SAFETY: the second USART1 handle goes to the transmitting half only, which writes DR's
    // transmit side and reads SR; the receiving half (the first handle) only reads SR and
    // DR's receive side. Nothing else uses USART1.
    let (usart1_rx, usart1_tx) = Usart::new(dp.USART1).split(unsafe { pac::USART1::steal() });
    let rx_bytes = defmt::unwrap!(cortex_m::singleton!(: RxBytes = RxBytes::new()));
    let (can, slcan) = SlcanLink::new(usart1_rx, usart1_tx, rx_bytes);
    let stimulus = StimulusLink::new(Usart::new(dp.USART2));

    Board {
        wheel: WheelInputs { _private: () },
        selectors: Selectors { _private: () },
        dip: 0,
        leds: Leds { _private: () },
        can,
        storage: RamStorage::new(defmt::unwrap!(cortex_m::singleton!(
            : [[u8; PAGE_SIZE]; PAGES] = [[0xFF; PAGE_SIZE]; PAGES]
        ))),
        watchdog: watchdog::Watchdog::new(),
        reset_cause: ResetCause::PowerOn,
        unique_id: UNIQUE_ID,
        own: Own { slcan, stimulus },
    }
}

/// The simulated wheel inputs: the levels the stimulus line last set.
pub struct WheelInputs {
    _private: (),
}

impl WheelInputs {
    /// Acknowledges an edge interrupt and returns the A/B levels after it. The "interrupt" is
    /// a software pend of EXTI9_5 (there is no EXTI to clear in QEMU).
    #[inline(always)]
    pub fn acknowledge_edge(&mut self) -> AbLevels {
        self.levels()
    }

    /// The current A/B levels (also the decoder's starting point at boot: A = B = 0).
    #[inline(always)]
    pub fn levels(&self) -> AbLevels {
        sim::ab()
    }
}

/// The simulated axis and multiplier switch lines.
pub struct Selectors {
    _private: (),
}

impl handwheel_core::SelectorInput for Selectors {
    /// The lines the stimulus set.
    fn read_lines(&mut self) -> (u8, u8) {
        sim::selector_masks()
    }
}

/// The indicator LEDs: the emulated board has none to drive.
pub struct Leds {
    _private: (),
}

impl Leds {
    /// Lights (`true`) or darkens each LED: nothing to see under QEMU.
    pub fn set(&mut self, _run: bool, _err: bool) {}
}

/// Why the MCU last came out of reset.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum ResetCause {
    /// The emulator started (QEMU has no reset flags; every start is a power-on).
    PowerOn,
}

/// The watchdog stand-in.
pub mod watchdog {
    /// QEMU does not model the independent watchdog (its registers are a stub), so there is
    /// nothing to start or feed: a hung `canopen` loop shows as a silent node instead of a
    /// reset.
    pub struct Watchdog {
        _private: (),
    }

    impl Watchdog {
        /// The stand-in.
        pub const fn new() -> Self {
            Self { _private: () }
        }

        /// Nothing to start.
        pub fn start(&mut self, _ms: u32) {}

        /// Nothing to feed.
        pub fn feed(&mut self) {}
    }

    impl Default for Watchdog {
        fn default() -> Self {
            Self::new()
        }
    }
}
