//! The board: clocks, pins, and the peripherals the application gets handed.
//!
//! Everything specific to the Blue Pill class STM32F103C8 board sits behind this module and
//! its siblings `can` and `storage`: a board variant (the QEMU build with HSI clock, USART
//! SLCAN and simulated pins) replaces `init` and the types it returns, and the RTIC
//! application above it stays as it is.

pub mod pins;
pub mod watchdog;

use crate::pac::{self, gpioa::RegisterBlock as Port};
use handwheel_core::AbLevels;

use crate::storage::FlashStorage;
use pins::{PortConfig, WHEEL_A_BIT, WHEEL_B_BIT, WHEEL_EXTI_LINES};
use watchdog::Watchdog;

/// The crystal on the board.
pub const HSE_HZ: u32 = 8_000_000;
/// Core clock (PLL x9), also the SysTick clock.
pub const SYSCLK_HZ: u32 = 72_000_000;
/// APB1 clock, the bxCAN kernel clock that the bit timing table is computed for.
pub const APB1_HZ: u32 = 36_000_000;

/// bxCAN, clocked and out of reset, ready for `bxcan::Can::builder`. Its pins (PB8/PB9,
/// remap 2) are set up by [`init`] with the rest of the pin map.
pub struct CanInstance {
    _can: pac::CAN,
    /// Held, never used: USB shares its packet SRAM with bxCAN (RM0008 24.1), so the two
    /// must not run together.
    _usb: pac::USB,
}

// SAFETY: the register block of bxCAN on this part is at CAN's address (RM0008 3.3, memory
// map) with the layout of RM0008 24.9, which `bxcan::RegisterBlock` models; owning
// `pac::CAN` makes `CanInstance` the one handle to it.
unsafe impl bxcan::Instance for CanInstance {
    const REGISTERS: *mut bxcan::RegisterBlock = pac::CAN::PTR as *mut _;
}

// SAFETY: the STM32F103 has one bxCAN (no CAN2 sharing the banks), which owns all 14 filter
// banks (RM0008 24.7.4).
unsafe impl bxcan::FilterOwner for CanInstance {
    const NUM_FILTER_BANKS: u8 = 14;
}

// SAFETY: the single bxCAN of the STM32F103 is a master instance (it has the filter banks).
unsafe impl bxcan::MasterInstance for CanInstance {}

/// The STM32F103 board's parts.
pub enum Parts {}

crate::parts::board_parts!(
    Parts: WheelInputs, Selectors, Leds, CanInstance, FlashStorage, Watchdog, ResetCause
);

/// Everything `init` sets up for the application.
pub type Board = crate::parts::Board<Parts>;

/// Brings up clocks and pins. Takes the device peripherals that RTIC's `init` hands over.
pub fn init(dp: pac::Peripherals) -> Board {
    let rcc = dp.RCC;
    start_clocks(&rcc, &dp.FLASH);
    let reset_cause = ResetCause::take(&rcc);
    rcc.apb2enr().modify(|_, w| {
        w.afioen()
            .set_bit()
            .iopaen()
            .set_bit()
            .iopben()
            .set_bit()
            .iopcen()
            .set_bit()
    });
    configure_port(&dp.GPIOA, pins::PORT_A);
    configure_port(&dp.GPIOB, pins::PORT_B);
    configure_port(&dp.GPIOC, pins::PORT_C);

    // Wheel: both edges of both channels on EXTI6/EXTI7 (they share the EXTI9_5 vector),
    // taken from port B. The CAN pins move to PB8/PB9; SWJ_CFG written as 0 keeps SWD.
    // SAFETY: EXTI6/EXTI7 = 1 selects port B, a valid source.
    dp.AFIO
        .exticr2()
        .modify(|_, w| unsafe { w.exti6().bits(1).exti7().bits(1) });
    // SAFETY: CAN_REMAP = 0b10 is the documented PB8/PB9 mapping.
    dp.AFIO
        .mapr()
        .modify(|_, w| unsafe { w.can_remap().bits(pins::CAN_REMAP_PB8_PB9) });
    let exti = dp.EXTI;
    // SAFETY: sets the two wheel lines' bits (rising edge), which exist on this part.
    exti.rtsr()
        .modify(|r, w| unsafe { w.bits(r.bits() | WHEEL_EXTI_LINES) });
    // SAFETY: sets the two wheel lines' bits (falling edge), which exist on this part.
    exti.ftsr()
        .modify(|r, w| unsafe { w.bits(r.bits() | WHEEL_EXTI_LINES) });
    // SAFETY: unmasks the two wheel lines, which exist on this part.
    exti.imr()
        .modify(|r, w| unsafe { w.bits(r.bits() | WHEEL_EXTI_LINES) });

    // The pull-ups need a moment to lift the open lines after the mode change.
    cortex_m::asm::delay(SYSCLK_HZ / 10_000);
    let dip = pins::dip_from_port(dp.GPIOB.idr().read().bits());

    // bxCAN's clock on, and a reset pulse so that it starts from its reset values.
    rcc.apb1enr().modify(|_, w| w.canen().set_bit());
    rcc.apb1rstr().modify(|_, w| w.canrst().set_bit());
    rcc.apb1rstr().modify(|_, w| w.canrst().clear_bit());
    let can = CanInstance {
        _can: dp.CAN,
        _usb: dp.USB,
    };

    let watchdog = Watchdog::new(dp.IWDG, &dp.DBGMCU);

    Board {
        wheel: WheelInputs { exti },
        selectors: Selectors { port: dp.GPIOA },
        dip,
        leds: Leds {
            port_b: dp.GPIOB,
            port_c: dp.GPIOC,
        },
        can,
        storage: FlashStorage::new(dp.FLASH),
        watchdog,
        reset_cause,
        unique_id: unique_id(),
    }
}

/// 72 MHz from the 8 MHz crystal: HSE, PLL x9, AHB /1, APB1 /2 (36 MHz, its maximum and the
/// bxCAN clock the bit timing table assumes), APB2 /1, and the two flash wait states with the
/// prefetch buffer that 48-72 MHz need (RM0008 7.3.1-7.3.2 for RCC, 3.3.3 for FLASH_ACR).
fn start_clocks(rcc: &pac::RCC, flash: &pac::FLASH) {
    const _: () = assert!(HSE_HZ * 9 == SYSCLK_HZ && SYSCLK_HZ / 2 == APB1_HZ);
    rcc.cr().modify(|_, w| w.hseon().set_bit());
    while rcc.cr().read().hserdy().bit_is_clear() {}
    // Wait states before the clock rises.
    // SAFETY: LATENCY = 2 is the documented setting for 48 < SYSCLK <= 72 MHz.
    flash
        .acr()
        .modify(|_, w| unsafe { w.latency().bits(2) }.prftbe().set_bit());
    rcc.cfgr().modify(|_, w| {
        w.pllsrc().set_bit(); // HSE, undivided (PLLXTPRE stays 0)
        w.pllmul().mul9();
        w.hpre().div1();
        w.ppre1().div2();
        w.ppre2().div1()
    });
    rcc.cr().modify(|_, w| w.pllon().set_bit());
    while rcc.cr().read().pllrdy().bit_is_clear() {}
    rcc.cfgr().modify(|_, w| w.sw().pll());
    while !rcc.cfgr().read().sws().is_pll() {}
}

/// Applies `config` to `port`: output levels first, so that an output starts at its level,
/// then the pin modes, one read-modify-write per configuration register.
fn configure_port(port: &Port, config: PortConfig) {
    // SAFETY: BSRR only sets or clears output data bits.
    port.bsrr().write(|w| unsafe { w.bits(config.bsrr()) });
    let [low_mask, high_mask] = [config.cr_mask as u32, (config.cr_mask >> 32) as u32];
    let [low_bits, high_bits] = [config.cr_bits as u32, (config.cr_bits >> 32) as u32];
    if low_mask != 0 {
        // SAFETY: the pin map's nibbles for its own pins of CRL; every other pin's nibble
        // is kept.
        port.crl()
            .modify(|r, w| unsafe { w.bits(r.bits() & !low_mask | low_bits) });
    }
    if high_mask != 0 {
        // SAFETY: as for CRL above, in CRH.
        port.crh()
            .modify(|r, w| unsafe { w.bits(r.bits() & !high_mask | high_bits) });
    }
}

/// The wheel's A/B inputs and the EXTI controller that signals their edges.
pub struct WheelInputs {
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
        // effects; GPIOB's writes (LED, at init the pin modes) never touch the wheel's bits.
        let idr = unsafe { (*pac::GPIOB::ptr()).idr().read().bits() };
        AbLevels::new(idr & (1 << WHEEL_A_BIT) != 0, idr & (1 << WHEEL_B_BIT) != 0)
    }
}

/// The axis and multiplier switches, read as one port.
pub struct Selectors {
    port: pac::GPIOA,
}

impl handwheel_core::SelectorInput for Selectors {
    /// All eight lines in one read of GPIOA.
    fn read_lines(&mut self) -> (u8, u8) {
        pins::selector_from_port(self.port.idr().read().bits())
    }
}

/// The CiA 303-3 indicator LEDs.
pub struct Leds {
    port_b: pac::GPIOB,
    port_c: pac::GPIOC,
}

impl Leds {
    /// Lights (`true`) or darkens each LED.
    pub fn set(&mut self, run: bool, err: bool) {
        // BSRR: bit n sets pin n, bit n + 16 clears it; no read-modify-write, so the
        // wheel's reads of GPIOB never race with it. PC13 sinks the on-board LED's current:
        // low lights it.
        let bsrr = |bit: u32, high: bool| if high { 1 << bit } else { 1 << (bit + 16) };
        // SAFETY: one set or clear bit of the RUN LED's own pin.
        self.port_c
            .bsrr()
            .write(|w| unsafe { w.bits(bsrr(pins::RUN_LED_BIT, !run)) });
        // SAFETY: one set or clear bit of the ERR LED's own pin.
        self.port_b
            .bsrr()
            .write(|w| unsafe { w.bits(bsrr(pins::ERR_LED_BIT, err)) });
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
    fn take(rcc: &pac::RCC) -> Self {
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
