//! The pin map: the one place that says which signal is on which pin.
//!
//! Mirrored in the README's pin table; change both together.
//!
//! | signal | pin | mode |
//! |---|---|---|
//! | CAN RX / TX | PB8 / PB9 | bxCAN remap 2 (PA11/PA12 are the board's USB) |
//! | wheel A / B | PB6 / PB7 | input, pull-up, EXTI6/EXTI7 both edges (`EXTI9_5`) |
//! | axis X, Y, Z, W, V | PA0, PA1, PA2, PA3, PA4 | input, pull-up, active low |
//! | multiplier x1, x10, x100 | PA5, PA6, PA7 | input, pull-up, active low |
//! | DIP 1..5 (node-ID bits 0..4) | PB12, PB13, PB14, PB15, PB0 | input, pull-up, on = low |
//! | DIP 6..8 (bit-rate code bits 0..2) | PB1, PB10, PB11 | input, pull-up, on = low |
//! | RUN LED (green) | PC13 | push-pull, active low (on the board) |
//! | ERR LED (red) | PB5 | push-pull, active high (external, to GND via a resistor) |
//!
//! SWD (PA13/PA14) stays free for the probe; PA9/PA10 (USART1) stay free for a serial
//! console or the SLCAN variant; PB3/PB4/PA15 are avoided because they start up as JTAG.
//!
//! The ports are configured with one read-modify-write per configuration register (below),
//! and the switches are read as whole ports: the HAL's pin-by-pin type states cost more
//! flash than the budget has room for, and these few registers are all the firmware needs.

/// Bit of wheel channel A in the GPIOB input data register (EXTI line 6).
pub const WHEEL_A_BIT: u32 = 6;
/// Bit of wheel channel B in the GPIOB input data register (EXTI line 7).
pub const WHEEL_B_BIT: u32 = 7;
/// The wheel's EXTI lines, as a mask of EXTI register bits.
pub const WHEEL_EXTI_LINES: u32 = 1 << WHEEL_A_BIT | 1 << WHEEL_B_BIT;

/// Axis lines X..V on GPIOA bits 0..4.
pub const AXIS_SHIFT: u32 = 0;
/// Multiplier lines x1, x10, x100 on GPIOA bits 5..7.
pub const MULTIPLIER_SHIFT: u32 = 5;

/// GPIOB bit of each DIP switch, switch 1 first.
pub const DIP_BITS: [u32; 8] = [12, 13, 14, 15, 0, 1, 10, 11];

/// ERR LED: GPIOB bit 5, lit when high.
pub const ERR_LED_BIT: u32 = 5;
/// RUN LED: GPIOC bit 13, lit when low.
pub const RUN_LED_BIT: u32 = 13;

/// CAN RX (PB8) and TX (PB9) with AFIO remap 2.
const CAN_RX_BIT: u32 = 8;
const CAN_TX_BIT: u32 = 9;
/// AFIO_MAPR CAN_REMAP value that puts bxCAN on PB8/PB9.
pub const CAN_REMAP_PB8_PB9: u8 = 0b10;

/// Pin configuration nibbles of GPIOx_CRL/CRH (CNF[1:0] MODE[1:0], RM0008 9.2.1).
const INPUT_PULL: u8 = 0b1000;
const OUTPUT_PUSH_PULL_2MHZ: u8 = 0b0010;
const ALTERNATE_PUSH_PULL_50MHZ: u8 = 0b1011;

/// How one port's pins are set up: the configuration registers' new nibbles (the other
/// pins keep theirs) and the output data register's bits, set through BSRR.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PortConfig {
    /// CRL (bits 0..32) and CRH (bits 32..64): mask of the nibbles this config owns.
    pub cr_mask: u64,
    /// Their new values.
    pub cr_bits: u64,
    /// Output data bits to set (pull-ups, outputs that start high).
    pub odr_set: u16,
    /// Output data bits to clear (pull-downs, outputs that start low).
    pub odr_reset: u16,
}

impl PortConfig {
    const NONE: Self = Self {
        cr_mask: 0,
        cr_bits: 0,
        odr_set: 0,
        odr_reset: 0,
    };

    const fn pin(self, bit: u32, nibble: u8, odr_high: bool) -> Self {
        let shift = bit * 4;
        Self {
            cr_mask: self.cr_mask | 0xF << shift,
            cr_bits: self.cr_bits | (nibble as u64) << shift,
            odr_set: self.odr_set | (odr_high as u16) << bit,
            odr_reset: self.odr_reset | (!odr_high as u16) << bit,
        }
    }

    const fn pulled_up_inputs(mut self, bits: &[u32]) -> Self {
        let mut i = 0;
        while i < bits.len() {
            self = self.pin(bits[i], INPUT_PULL, true);
            i += 1;
        }
        self
    }

    /// The value for BSRR: set bits low, reset bits high.
    pub const fn bsrr(self) -> u32 {
        self.odr_set as u32 | (self.odr_reset as u32) << 16
    }
}

/// GPIOA: the axis and multiplier switches, pulled up.
pub const PORT_A: PortConfig = PortConfig::NONE.pulled_up_inputs(&[0, 1, 2, 3, 4, 5, 6, 7]);

/// GPIOB: wheel, DIP switch and CAN RX pulled up, CAN TX to bxCAN, ERR LED off.
pub const PORT_B: PortConfig = PortConfig::NONE
    .pulled_up_inputs(&[WHEEL_A_BIT, WHEEL_B_BIT, CAN_RX_BIT])
    .pulled_up_inputs(&DIP_BITS)
    .pin(CAN_TX_BIT, ALTERNATE_PUSH_PULL_50MHZ, true)
    .pin(ERR_LED_BIT, OUTPUT_PUSH_PULL_2MHZ, false);

/// GPIOC: RUN LED off (high).
pub const PORT_C: PortConfig = PortConfig::NONE.pin(RUN_LED_BIT, OUTPUT_PUSH_PULL_2MHZ, true);

/// The DIP switch from GPIOB's input data: bit `i` set = switch `i + 1` on (pin low).
pub const fn dip_from_port(idr: u32) -> u8 {
    let mut dip = 0;
    let mut switch = 0;
    while switch < DIP_BITS.len() {
        if idr & 1 << DIP_BITS[switch] == 0 {
            dip |= 1 << switch;
        }
        switch += 1;
    }
    dip
}

/// The active axis and multiplier line masks from GPIOA's input data (lines are active low).
pub const fn selector_from_port(idr: u32) -> (u8, u8) {
    let active = !idr;
    (
        (active >> AXIS_SHIFT) as u8 & 0x1F,
        (active >> MULTIPLIER_SHIFT) as u8 & 0x07,
    )
}

// The pin map's own consistency, checked at build time: no pin is configured twice, the
// JTAG and SWD pins stay untouched, and the readers see the lines the table names.
const _: () = {
    let b = PORT_B;
    // 11 inputs + CAN TX + ERR LED, each one nibble.
    assert!(b.cr_mask.count_ones() == 13 * 4);
    // PB3/PB4 (JTAG) untouched.
    assert!(b.cr_mask & (0xF << 12 | 0xF << 16) == 0);
    assert!(PORT_A.cr_mask == 0xFFFF_FFFF);
    assert!(PORT_A.odr_set == 0xFF && PORT_A.odr_reset == 0);
    assert!(PORT_C.odr_set == 1 << 13);
    assert!(PORT_B.odr_reset == 1 << ERR_LED_BIT);
    // All switches open (pins high): nothing on; switch 5 closed: bit 4 (PB0).
    assert!(dip_from_port(0xFFFF) == 0);
    assert!(dip_from_port(0xFFFF & !1) == 1 << 4);
    assert!(dip_from_port(0) == 0xFF);
    let (axis, multiplier) = selector_from_port(0xFFFF & !(1 << 2) & !(1 << 6));
    assert!(axis == 1 << 2 && multiplier == 1 << 1);
};
