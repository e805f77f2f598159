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
//!
//! SWD (PA13/PA14) stays free for the probe; PA9/PA10 (USART1) stay free for a serial
//! console; PB3/PB4/PA15 are avoided because they start up as JTAG.

/// Bit of wheel channel A in the GPIOB input data register (PB6, EXTI line 6).
pub const WHEEL_A_BIT: u32 = 6;
/// Bit of wheel channel B in the GPIOB input data register (PB7, EXTI line 7).
pub const WHEEL_B_BIT: u32 = 7;
