//! The pin map: the one place that says which signal is on which pin.
//!
//! Mirrored in the README's pin table; change both together. `board::init` puts each pin in
//! its mode with the HAL, in this order.
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
