//! The board: clocks, pins, and the peripherals the application gets handed.
//!
//! Everything specific to the Blue Pill class STM32F103C8 board sits behind this module and
//! its siblings `can` and `storage`: a board variant (the QEMU build with HSI clock, USART
//! SLCAN and simulated pins) replaces `init` and the types it returns, and the RTIC
//! application above it stays as it is.

pub mod pins;
pub mod watchdog;

use handwheel_core::{AbLevels, SelectorLines};
use stm32f1xx_hal::{
    can::Can,
    flash,
    gpio::{Edge, ExtiPin, PinState, PullUp},
    pac,
    prelude::*,
    rcc::{self, Rcc},
};

use crate::storage::FlashStorage;
use pins::{ErrLed, RunLed, SwitchLine, WheelA, WheelB, WHEEL_A_BIT, WHEEL_B_BIT};
use watchdog::Watchdog;

/// The crystal on the board.
pub const HSE_HZ: u32 = 8_000_000;
/// Core clock (PLL x9), also the SysTick clock.
pub const SYSCLK_HZ: u32 = 72_000_000;
/// APB1 clock, the bxCAN kernel clock that the bit timing table is computed for.
pub const APB1_HZ: u32 = 36_000_000;

/// The bxCAN peripheral with its pins, ready for `bxcan::Can::builder`.
pub type CanInstance = Can<pac::CAN, PullUp>;

/// The selector lines: 5 axis lines and 3 multiplier lines, read by `handwheel-core`.
pub type Selectors = SelectorLines<SwitchLine>;

/// Everything `init` sets up for the application.
pub struct Board {
    /// Wheel A/B inputs and the EXTI lines they trigger.
    pub wheel: WheelInputs,
    /// Axis and multiplier switch lines.
    pub selectors: Selectors,
    /// DIP switch, read once at start-up: bit `i` set = switch `i + 1` on.
    pub dip: u8,
    /// RUN and ERR LEDs.
    pub leds: Leds,
    /// bxCAN with its remapped pins, not yet configured.
    pub can: CanInstance,
    /// The parameter page in flash.
    pub storage: FlashStorage,
    /// Independent watchdog, not started yet.
    pub watchdog: Watchdog,
    /// Why the MCU last reset.
    pub reset_cause: ResetCause,
    /// The MCU's 96-bit unique ID.
    pub unique_id: [u32; 3],
}

/// Brings up clocks and pins. Takes the device peripherals that RTIC's `init` hands over.
pub fn init(dp: pac::Peripherals) -> Board {
    let mut flash = dp.FLASH.constrain();
    let mut rcc = dp.RCC.freeze(
        rcc::Config::hse(HSE_HZ.Hz())
            .sysclk(SYSCLK_HZ.Hz())
            .hclk(SYSCLK_HZ.Hz())
            .pclk1(APB1_HZ.Hz())
            .pclk2(SYSCLK_HZ.Hz()),
        &mut flash.acr,
    );
    // The bit timing table and the SysTick rate assume these exact clocks.
    defmt::assert_eq!(rcc.clocks.sysclk().raw(), SYSCLK_HZ);
    defmt::assert_eq!(rcc.clocks.pclk1().raw(), APB1_HZ);

    let reset_cause = ResetCause::take(&mut rcc);
    let mut afio = dp.AFIO.constrain(&mut rcc);
    let mut gpioa = dp.GPIOA.split(&mut rcc);
    let mut gpiob = dp.GPIOB.split(&mut rcc);
    let mut gpioc = dp.GPIOC.split(&mut rcc);

    // Wheel: both edges of both channels on EXTI6/EXTI7 (they share the EXTI9_5 vector).
    let mut exti = dp.EXTI;
    let mut a: WheelA = gpiob.pb6.into_pull_up_input(&mut gpiob.crl);
    let mut b: WheelB = gpiob.pb7.into_pull_up_input(&mut gpiob.crl);
    for pin in [&mut a as &mut dyn ExtiPin, &mut b] {
        pin.make_interrupt_source(&mut afio);
        pin.trigger_on_edge(&mut exti, Edge::RisingFalling);
        pin.enable_interrupt(&mut exti);
    }
    let wheel = WheelInputs { _a: a, _b: b, exti };

    let selectors = SelectorLines {
        axis: [
            gpioa.pa0.into_pull_up_input(&mut gpioa.crl).erase(),
            gpioa.pa1.into_pull_up_input(&mut gpioa.crl).erase(),
            gpioa.pa2.into_pull_up_input(&mut gpioa.crl).erase(),
            gpioa.pa3.into_pull_up_input(&mut gpioa.crl).erase(),
            gpioa.pa4.into_pull_up_input(&mut gpioa.crl).erase(),
        ],
        multiplier: [
            gpioa.pa5.into_pull_up_input(&mut gpioa.crl).erase(),
            gpioa.pa6.into_pull_up_input(&mut gpioa.crl).erase(),
            gpioa.pa7.into_pull_up_input(&mut gpioa.crl).erase(),
        ],
    };

    let dip_lines: [SwitchLine; 8] = [
        gpiob.pb12.into_pull_up_input(&mut gpiob.crh).erase(),
        gpiob.pb13.into_pull_up_input(&mut gpiob.crh).erase(),
        gpiob.pb14.into_pull_up_input(&mut gpiob.crh).erase(),
        gpiob.pb15.into_pull_up_input(&mut gpiob.crh).erase(),
        gpiob.pb0.into_pull_up_input(&mut gpiob.crl).erase(),
        gpiob.pb1.into_pull_up_input(&mut gpiob.crl).erase(),
        gpiob.pb10.into_pull_up_input(&mut gpiob.crh).erase(),
        gpiob.pb11.into_pull_up_input(&mut gpiob.crh).erase(),
    ];
    // The pull-ups need a moment to lift the open lines after the mode change.
    cortex_m::asm::delay(SYSCLK_HZ / 10_000);
    let dip = read_active_low(&dip_lines);

    let leds = Leds {
        run: gpioc
            .pc13
            .into_push_pull_output_with_state(&mut gpioc.crh, PinState::High),
        err: gpiob
            .pb5
            .into_push_pull_output_with_state(&mut gpiob.crl, PinState::Low),
    };

    // CAN on PB8 (RX) / PB9 (TX): AFIO remap 2. The USB peripheral is consumed because it
    // shares its packet SRAM with bxCAN.
    let can_rx = gpiob.pb8.into_pull_up_input(&mut gpiob.crh);
    let can = dp
        .CAN
        .remap::<2>(&mut afio.mapr)
        .can(dp.USB, (gpiob.pb9, can_rx), &mut rcc);

    let watchdog = Watchdog::new(dp.IWDG, &dp.DBGMCU);

    Board {
        wheel,
        selectors,
        dip,
        leds,
        can,
        storage: FlashStorage::new(flash),
        watchdog,
        reset_cause,
        unique_id: unique_id(),
    }
}

/// Mask of the lines that read low (switch closed to ground), bit `i` = `lines[i]`.
fn read_active_low(lines: &[SwitchLine]) -> u8 {
    lines
        .iter()
        .enumerate()
        .filter(|(_, line)| line.is_low())
        .fold(0, |mask, (bit, _)| mask | (1 << bit))
}

/// The wheel's A/B inputs and the EXTI controller that signals their edges.
pub struct WheelInputs {
    // Owned so that nothing else reconfigures the pins; read through the port register.
    _a: WheelA,
    _b: WheelB,
    exti: pac::EXTI,
}

impl WheelInputs {
    /// Acknowledges an edge interrupt and returns the A/B levels after it.
    ///
    /// The pending bits are cleared first and the port read second: an edge that lands
    /// between the two sets the pending bit again and the interrupt runs once more, so no
    /// edge is missed. Both channels come from one read of GPIOB's input register, so the
    /// decoder always sees a consistent pair.
    #[inline(always)]
    pub fn acknowledge_edge(&mut self) -> AbLevels {
        self.exti.pr().write(|w| w.pr6().clear().pr7().clear());
        self.levels()
    }

    /// The current A/B levels (also the decoder's starting point at boot).
    #[inline(always)]
    pub fn levels(&self) -> AbLevels {
        // SAFETY: a read of GPIOB's input data register, which is read-only and has no side
        // effects; the pins' configuration is owned by this struct and not touched here.
        let idr = unsafe { (*pac::GPIOB::ptr()).idr().read().bits() };
        AbLevels::new(idr & (1 << WHEEL_A_BIT) != 0, idr & (1 << WHEEL_B_BIT) != 0)
    }
}

/// The CiA 303-3 indicator LEDs.
pub struct Leds {
    run: RunLed,
    err: ErrLed,
}

impl Leds {
    /// Lights (`true`) or darkens each LED.
    pub fn set(&mut self, run: bool, err: bool) {
        // PC13 sinks the on-board LED's current: low lights it.
        self.run.set_state(PinState::from(!run));
        self.err.set_state(PinState::from(err));
    }
}

/// Why the MCU last came out of reset (RCC_CSR flags, highest-priority cause first).
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum ResetCause {
    /// The independent watchdog expired: the CAN-side work loop stopped running.
    IndependentWatchdog,
    /// The window watchdog (unused by this firmware).
    WindowWatchdog,
    /// A software reset (NMT reset node, or a debugger).
    Software,
    /// Low-power management reset.
    LowPower,
    /// Power-on or brown-out.
    PowerOn,
    /// The NRST pin (reset button or probe).
    Pin,
    /// No flag set.
    Unknown,
}

impl ResetCause {
    /// Reads the reset flags and clears them for the next boot.
    fn take(rcc: &mut Rcc) -> Self {
        let csr = rcc.csr().read();
        let cause = if csr.iwdgrstf().bit_is_set() {
            Self::IndependentWatchdog
        } else if csr.wwdgrstf().bit_is_set() {
            Self::WindowWatchdog
        } else if csr.sftrstf().bit_is_set() {
            Self::Software
        } else if csr.lpwrrstf().bit_is_set() {
            Self::LowPower
        } else if csr.porrstf().bit_is_set() {
            Self::PowerOn
        } else if csr.pinrstf().bit_is_set() {
            Self::Pin
        } else {
            Self::Unknown
        };
        rcc.csr().modify(|_, w| w.rmvf().set_bit());
        cause
    }
}

/// Address of the 96-bit unique device ID (RM0008, "Unique device ID register").
const UNIQUE_ID_ADDRESS: usize = 0x1FFF_F7E8;

/// The MCU's 96-bit unique ID as three words, lowest address first.
pub fn unique_id() -> [u32; 3] {
    let base = UNIQUE_ID_ADDRESS as *const u32;
    core::array::from_fn(|word| {
        // SAFETY: the unique ID is factory-programmed system memory at a fixed, word-aligned
        // address on every STM32F1; `word` < 3 keeps the read inside its 12 bytes, and the
        // read has no side effects.
        unsafe { core::ptr::read_volatile(base.add(word)) }
    })
}

/// Re-export for the storage module: the constrained flash peripheral.
pub type FlashParts = flash::Parts;
