//! The board: clocks, pins, and the peripherals the application gets handed, brought up with
//! stm32f1xx-hal.
//!
//! Everything specific to the Blue Pill class STM32F103C8 board sits behind this module and
//! its siblings `can` and `storage`; the RTIC application gets its parts from [`init`].
//!
//! The HAL does the clock tree (`rcc`), the pin modes, the AFIO remap of bxCAN to PB8/PB9,
//! the wheel's EXTI lines (`ExtiPin`), the bxCAN clock and pins (`can::Can`), the flash
//! writer and the watchdog. What it has no API for is done by hand here, each with its
//! reason: the reset cause (RCC_CSR), the unique ID, and the one read of GPIOB's input
//! register that yields A and B together (the HAL reads a pin at a time).

/// The pin map (in the board crate, which the resident loader shares).
pub use handwheel_board::pins;

use handwheel_core::AbLevels;
use stm32f1xx_hal::{
    can::Can,
    gpio::{
        self, Edge, ExtiPin, IOPinSpeed, Input, Output, OutputSpeed, PinState, PullUp, PushPull,
    },
    pac,
    prelude::*,
    rcc,
};

use crate::storage::{parameter_pages, FlashStorage};
pub use handwheel_board::watchdog::Watchdog;
use pins::{WHEEL_A_BIT, WHEEL_B_BIT};

pub use handwheel_board::chip::unique_id;
pub use handwheel_board::clocks::{APB1_HZ, HSE_HZ, SYSCLK_HZ};

/// The HAL's bxCAN (clocked, its pins PB8/PB9 in their remap-2 modes), for
/// `bxcan::Can::builder`.
///
/// A wrapper, not the HAL's `Can` itself, for one reason: the HAL's `bxcan::FilterOwner`
/// claims 28 filter banks on every part, the connectivity line's count; the STM32F103 has 14
/// (RM0008 24.7.4). This is the one place that says so. (bxcan only uses the count to split
/// banks between two instances, which this part does not have, and takes the banks in use
/// from CAN_FMR; still, the firmware states the right number.)
pub struct CanInstance {
    _can: Can<pac::CAN, PullUp>,
}

// SAFETY: the register block of bxCAN on this part is at CAN's address (RM0008 3.3, memory
// map) with the layout of RM0008 24.9, which `bxcan::RegisterBlock` models; `CanInstance`
// owns the HAL's `Can`, which owns `pac::CAN` (and `pac::USB`, which shares bxCAN's SRAM),
// so it is the one handle to it.
unsafe impl bxcan::Instance for CanInstance {
    const REGISTERS: *mut bxcan::RegisterBlock = pac::CAN::PTR as *mut _;
}

// SAFETY: the STM32F103 has one bxCAN (no CAN2 sharing the banks), which owns all 14 filter
// banks (RM0008 24.7.4).
unsafe impl bxcan::FilterOwner for CanInstance {
    const NUM_FILTER_BANKS: u8 = 14;
}

pub use crate::storage::DeviceStorage;

/// Everything [`init`] sets up for the application.
pub struct Board {
    /// Wheel A/B inputs, handed to the edge interrupt.
    pub wheel: WheelInputs,
    /// Axis and multiplier switch lines.
    pub selectors: Selectors,
    /// DIP switch, read once at start-up: bit `i` set = switch `i + 1` on.
    pub dip: u8,
    /// RUN and ERR LEDs.
    pub leds: Leds,
    /// The digital outputs: "jog live" and the CNC's (0x6A00).
    pub outputs: DigitalOutputs,
    /// The CAN controller, not yet started.
    pub can: CanInstance,
    /// Where 0x1010 stores parameters.
    pub storage: FlashStorage,
    /// The independent watchdog, not started yet.
    pub watchdog: Watchdog,
    /// Why the MCU last reset.
    pub reset_cause: ResetCause,
    /// The MCU's 96-bit unique ID.
    pub unique_id: [u32; 3],
}

/// Brings up clocks and pins. Takes the device peripherals that RTIC's `init` hands over.
pub fn init(dp: pac::Peripherals) -> Board {
    let mut flash = dp.FLASH.constrain();
    // The board's clocks (handwheel_board::clocks, the loader's too).
    let mut rcc = handwheel_board::clocks::freeze(dp.RCC, &mut flash.acr);
    let reset_cause = ResetCause::take(&rcc);

    let mut afio = dp.AFIO.constrain(&mut rcc);
    let mut gpioa = dp.GPIOA.split(&mut rcc);
    let mut gpiob = dp.GPIOB.split(&mut rcc);
    let mut gpioc = dp.GPIOC.split(&mut rcc);

    // Axis X..V on PA0..PA4, multiplier x1, x10, x100 on PA5..PA7: pulled up, active low.
    let selectors = Selectors {
        axis: [
            gpioa.pa0.into_pull_up_input(&mut gpioa.crl).erase_number(),
            gpioa.pa1.into_pull_up_input(&mut gpioa.crl).erase_number(),
            gpioa.pa2.into_pull_up_input(&mut gpioa.crl).erase_number(),
            gpioa.pa3.into_pull_up_input(&mut gpioa.crl).erase_number(),
            gpioa.pa4.into_pull_up_input(&mut gpioa.crl).erase_number(),
        ],
        multiplier: [
            gpioa.pa5.into_pull_up_input(&mut gpioa.crl).erase_number(),
            gpioa.pa6.into_pull_up_input(&mut gpioa.crl).erase_number(),
            gpioa.pa7.into_pull_up_input(&mut gpioa.crl).erase_number(),
        ],
    };
    // The DIP switch, read as the loader reads it (handwheel_board::pins).
    let dip = handwheel_board::read_dip_switch!(gpiob);

    // The LEDs start dark: RUN (PC13) sinks the on-board LED's current, ERR (PB5) sources.
    let mut run = gpioc
        .pc13
        .into_push_pull_output_with_state(&mut gpioc.crh, PinState::High);
    run.set_speed(&mut gpioc.crh, IOPinSpeed::Mhz2);
    let mut err = gpiob
        .pb5
        .into_push_pull_output_with_state(&mut gpiob.crl, PinState::Low);
    err.set_speed(&mut gpiob.crl, IOPinSpeed::Mhz2);

    // The digital outputs, off (low) from here on. PA15, PB3 and PB4 come out of reset as
    // JTAG's; SWJ_CFG = 0b010 frees them and keeps SWD (the HAL writes that into every later
    // MAPR write too, bxCAN's remap below included). PC14 sits behind the backup domain's
    // switch: 2 MHz, as all of them (slow edges, no load current to speak of).
    let (pa15, pb3, pb4) = afio.mapr.disable_jtag(gpioa.pa15, gpiob.pb3, gpiob.pb4);
    macro_rules! output {
        ($pin:expr, $cr:expr) => {{
            let mut pin = $pin.into_push_pull_output_with_state($cr, PinState::Low);
            pin.set_speed($cr, IOPinSpeed::Mhz2);
            pin.erase()
        }};
    }
    let outputs = DigitalOutputs {
        pins: [
            output!(gpioa.pa8, &mut gpioa.crh),
            output!(pa15, &mut gpioa.crh),
            output!(pb3, &mut gpiob.crl),
            output!(pb4, &mut gpiob.crl),
            output!(gpioa.pa9, &mut gpioa.crh),
            output!(gpioa.pa10, &mut gpioa.crh),
            output!(gpiob.pb2, &mut gpiob.crl),
            output!(gpioc.pc14, &mut gpioc.crh),
        ],
    };

    // Wheel: both edges of both channels on EXTI6/EXTI7 (they share the EXTI9_5 vector).
    let mut exti = dp.EXTI;
    let mut a = gpiob.pb6.into_pull_up_input(&mut gpiob.crl);
    let mut b = gpiob.pb7.into_pull_up_input(&mut gpiob.crl);
    a.make_interrupt_source(&mut afio);
    b.make_interrupt_source(&mut afio);
    a.trigger_on_edge(&mut exti, Edge::RisingFalling);
    b.trigger_on_edge(&mut exti, Edge::RisingFalling);
    a.enable_interrupt(&mut exti);
    b.enable_interrupt(&mut exti);

    // bxCAN on the board's pins, as the loader opens it (handwheel_board::pins).
    let can = handwheel_board::open_can!(dp, afio, gpiob, rcc);

    let watchdog = Watchdog::new(dp.IWDG, &dp.DBGMCU);

    Board {
        wheel: WheelInputs { a, b },
        selectors,
        dip,
        leds: Leds { run, err },
        outputs,
        can: CanInstance { _can: can },
        storage: parameter_pages(flash),
        watchdog,
        reset_cause,
        unique_id: unique_id(),
    }
}

/// The wheel's A/B inputs (PB6, PB7), the EXTI sources of its interrupt.
pub struct WheelInputs {
    a: gpio::PB6<Input<PullUp>>,
    b: gpio::PB7<Input<PullUp>>,
}

impl WheelInputs {
    /// Acknowledges an edge interrupt and returns the A/B levels after it.
    ///
    /// The pending bits are cleared first (the HAL's `ExtiPin`) and the port read second: an
    /// edge that lands between the two sets the pending bit again and the interrupt runs once
    /// more, so no edge is missed.
    #[inline(always)]
    pub fn acknowledge_edge(&mut self) -> AbLevels {
        self.a.clear_interrupt_pending_bit();
        self.b.clear_interrupt_pending_bit();
        self.levels()
    }

    /// The current A/B levels (also the decoder's starting point at boot).
    ///
    /// Register access by hand: the HAL reads one pin per read of the input data register,
    /// and the decoder needs A and B from the same instant, so both come from one read.
    #[inline(always)]
    pub fn levels(&self) -> AbLevels {
        // SAFETY: a read of GPIOB's input data register, which is read-only and has no side
        // effects; the pins it looks at are `self.a` and `self.b`, owned here.
        let idr = unsafe { (*pac::GPIOB::ptr()).idr().read().bits() };
        AbLevels::new(idr & (1 << WHEEL_A_BIT) != 0, idr & (1 << WHEEL_B_BIT) != 0)
    }
}

/// The axis and multiplier switch lines (HAL pins, read one by one every 5 ms).
pub struct Selectors {
    axis: [gpio::PEPin<'A', Input<PullUp>>; 5],
    multiplier: [gpio::PEPin<'A', Input<PullUp>>; 3],
}

/// The mask of the active (low) lines among `pins`, line `i` in bit `i`.
fn active_lines(pins: &[gpio::PEPin<'A', Input<PullUp>>]) -> u8 {
    pins.iter()
        .enumerate()
        .fold(0, |mask, (i, pin)| mask | u8::from(pin.is_low()) << i)
}

impl handwheel_core::SelectorInput for Selectors {
    fn read_lines(&mut self) -> (u8, u8) {
        (active_lines(&self.axis), active_lines(&self.multiplier))
    }
}

/// The CiA 303-3 indicator LEDs.
pub struct Leds {
    run: gpio::PC13<Output<PushPull>>,
    err: gpio::PB5<Output<PushPull>>,
}

impl Leds {
    /// Lights (`true`) or darkens each LED. PC13 sinks the on-board LED's current: low
    /// lights it. (Each is one BSRR write: no read-modify-write of the port.)
    pub fn set(&mut self, run: bool, err: bool) {
        self.run.set_state(PinState::from(!run));
        self.err.set_state(PinState::from(err));
    }
}

/// The board's eight digital outputs, push-pull, active high, in board order: out 1 the
/// "jog live" LED (PA8), outs 2..8 the bits 0..6 of 0x6A00:1 (PA15, PB3, PB4, PA9, PA10, PB2,
/// PC14). Bit 7 of 0x6A00:1 has no pin.
pub struct DigitalOutputs {
    pins: [gpio::ErasedPin<Output<PushPull>>; 8],
}

impl DigitalOutputs {
    /// Drives out 1 with `jog_live` and outs 2..8 with bits 0..6 of `written`. (Each pin is
    /// one BSRR write: no read-modify-write of a port.)
    pub fn set(&mut self, jog_live: bool, written: u8) {
        let levels = u16::from(written) << 1 | u16::from(jog_live);
        for (i, pin) in self.pins.iter_mut().enumerate() {
            pin.set_state(PinState::from(levels >> i & 1 != 0));
        }
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
    ///
    /// Register access by hand (through the HAL's `Rcc`, which derefs to the PAC's RCC): the
    /// HAL has no API for the reset cause.
    fn take(rcc: &rcc::Rcc) -> Self {
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
