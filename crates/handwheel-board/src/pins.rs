//! The pin map: the one place that says which signal is on which pin, for both images.
//!
//! Mirrored in the README's pin table and the wiring diagram (`cargo xtask docs --check`
//! compares them). The application's `board::init` (src/board/mod.rs) puts each pin in its
//! mode with the HAL; the DIP switch and bxCAN's pins, which the resident loader sets up too
//! (it must answer at the application's node-ID and bit rate), are brought up by the macros
//! below in both images, so that a switch moved here moves in both.
//!
//! | signal | pin | mode |
//! |---|---|---|
//! | CAN RX / TX | PB8 / PB9 | bxCAN remap 2 (PA11/PA12 are the board's USB) |
//! | wheel A / B | PB6 / PB7 | input, pull-up, EXTI6/EXTI7 both edges (`EXTI9_5`) |
//! | axis X, Y, Z, W, V | PA0, PA1, PA2, PA3, PA4 | input, pull-up, active low |
//! | multiplier x1, x10, x100 | PA5, PA6, PA7 | input, pull-up, active low |
//! | DIP 1..5 (node-ID bits 0..4) | PB12, PB13, PB14, PB15, PB0 | input, pull-up, on = low |
//! | DIP 6..8 (bit-rate code bits 0..2) | PB1, PB10, PB11 | input, pull-up, on = low |
//! | RUN LED (green) | PC13 | push-pull 2 MHz, active low (on the board) |
//! | ERR LED (red) | PB5 | push-pull 2 MHz, active high (external, to GND via a resistor) |
//! | out 1: jog live LED | PA8 | push-pull 2 MHz, active high (the device's "jog live", 0x2036) |
//! | out 2..4: 0x6A00 bits 0..2 | PA15, PB3, PB4 | push-pull 2 MHz, active high; JTAG pins, freed by SWJ_CFG = 0b010 (SWD kept) |
//! | out 5, 6: 0x6A00 bits 3, 4 | PA9, PA10 | push-pull 2 MHz, active high (USART1's pins: no serial console) |
//! | out 7: 0x6A00 bit 5 | PB2 | push-pull 2 MHz, active high (BOOT1, read only at reset) |
//! | out 8: 0x6A00 bit 6 | PC14 | push-pull 2 MHz, active high; logic level only (3 mA, no LED) |
//!
//! SWD (PA13/PA14) stays free for the probe. The outputs are off (low) from `board::init` on,
//! floating inputs before it (in the loader too): a load that must not float wants a
//! pull-down. 0x6A00 bit 7 has no pin. PC14 is one of the three pins behind the backup
//! domain's power switch (RM0008 5.1.2, datasheet 5.3.13): at most 3 mA, 2 MHz, 30 pF and
//! never a current source, so it drives a logic input (a buffer, an opto driver's input
//! stage) and PC15, the other one, stays free.

/// Bit of wheel channel A in the GPIOB input data register (PB6, EXTI line 6).
pub const WHEEL_A_BIT: u32 = 6;
/// Bit of wheel channel B in the GPIOB input data register (PB7, EXTI line 7).
pub const WHEEL_B_BIT: u32 = 7;

/// bxCAN's AFIO remap: 2, RX on PB8 and TX on PB9 (PA11/PA12 are the board's USB).
pub const CAN_REMAP: u8 = 2;

/// Reads the DIP switch once, as both images do at start: switches 1..8 on PB12, PB13,
/// PB14, PB15, PB0, PB1, PB10, PB11, pulled up, on = low; bit `i` of the result set =
/// switch `i + 1` on. `$gpiob` is the HAL's split GPIOB (`gpiob::Parts`); the eight pins
/// are moved out of it and stay inputs with their pull-ups.
#[cfg(target_os = "none")]
#[macro_export]
macro_rules! read_dip_switch {
    ($gpiob:ident) => {{
        let dip_pins = [
            $gpiob.pb12.into_pull_up_input(&mut $gpiob.crh).erase(),
            $gpiob.pb13.into_pull_up_input(&mut $gpiob.crh).erase(),
            $gpiob.pb14.into_pull_up_input(&mut $gpiob.crh).erase(),
            $gpiob.pb15.into_pull_up_input(&mut $gpiob.crh).erase(),
            $gpiob.pb0.into_pull_up_input(&mut $gpiob.crl).erase(),
            $gpiob.pb1.into_pull_up_input(&mut $gpiob.crl).erase(),
            $gpiob.pb10.into_pull_up_input(&mut $gpiob.crh).erase(),
            $gpiob.pb11.into_pull_up_input(&mut $gpiob.crh).erase(),
        ];
        // The pull-ups need a moment to lift the open lines after the mode change.
        $crate::delay($crate::clocks::PULL_UP_SETTLE_CYCLES);
        dip_pins.iter().enumerate().fold(0u8, |dip, (switch, pin)| {
            dip | u8::from(pin.is_low()) << switch
        })
    }};
}

/// The HAL's bxCAN on the board's pins: AFIO remap [`CAN_REMAP`], TX PB9, RX PB8 pulled up
/// (MAPR's SWJ_CFG as the HAL keeps it: SWD stays). `$dp` the PAC's peripherals (its `CAN`
/// and `USB`, which shares bxCAN's packet SRAM, are moved), `$afio` the constrained AFIO,
/// `$gpiob` as in [`read_dip_switch`], `$rcc` the frozen RCC.
#[cfg(target_os = "none")]
#[macro_export]
macro_rules! open_can {
    ($dp:ident, $afio:ident, $gpiob:ident, $rcc:ident) => {{
        use $crate::hal::afio::Remap as _;
        $crate::hal::can::Can::new(
            $dp.CAN
                .remap::<{ $crate::pins::CAN_REMAP }>(&mut $afio.mapr),
            $dp.USB,
            ($gpiob.pb9, $gpiob.pb8.into_pull_up_input(&mut $gpiob.crh)),
            &mut $rcc,
        )
    }};
}
