//! The stimulus line on USART2: the test harness (or the demo) turns the simulated wheel and
//! sets the simulated switch lines.
//!
//! Commands and replies are `sim_io::stimulus`'s: `turn <n>`, `ab <0..3>`,
//! `axis <off|x|y|z|w|v>`, `mult <1|10|100>`, each answered with `ok` once applied or
//! `err <reason>`.
//!
//! The QEMU variant's USART2 task (`qemu_usart2` in `src/main.rs`, priority 3, below the
//! wheel's EXTI task) does all of it through [`StimulusLink::on_interrupt`]; it shares
//! nothing with the rest of the app but the simulated lines ([`sim`](super::sim)), which are
//! atomics. `stall <ms>` is handed to the app, which holds the CAN side busy that long.
//!
//! A wheel edge is made the way the board sees one: the new A/B levels go to the simulated
//! port and the EXTI9_5 interrupt is pended, so the shipping edge task (`wheel_edge`)
//! reads and decodes them. It has the highest priority, so it runs at once (after the `isb`, which
//! keeps back-to-back pends from merging); each edge is handled before the next is made, and
//! `turn` replies after its last edge. Selector commands only set the lines: the `canopen`
//! task's sampling and debouncing of the switches decide when the selection changes (4
//! samples, 5 ms apart).

use crate::pac::{self, Interrupt};
use cortex_m::peripheral::NVIC;
use handwheel_core::AbLevels;
use sim_io::stimulus::{self, Command, StimError, StimulusPort};

use super::{sim, usart::Usart};

/// Quadrature edges per detent the simulated wheel makes: one full A/B cycle.
pub const EDGES_PER_DETENT: u32 = 4;

/// USART2 and the command line assembler.
pub struct StimulusLink {
    usart: Usart<pac::USART2>,
    port: StimulusPort,
}

impl StimulusLink {
    /// The line on the enabled USART2.
    pub fn new(usart: Usart<pac::USART2>) -> Self {
        Self {
            usart,
            port: StimulusPort::new(),
        }
    }

    /// USART2 received a byte: applies every completed command line and answers it;
    /// `stall(ms)` for a `stall` command.
    pub fn on_interrupt(&mut self, mut stall: impl FnMut(u16)) {
        while let Some(byte) = self.usart.read() {
            if let Some(command) = self.port.push(byte) {
                let result = command.and_then(|command| apply(command, &mut stall));
                self.usart.write_all(stimulus::render(result).as_bytes());
            }
        }
    }
}

/// Carries out one command.
fn apply(command: Command, stall: &mut impl FnMut(u16)) -> Result<(), StimError> {
    match command {
        Command::Turn(detents) => {
            let mut levels = sim::ab();
            for _ in 0..detents.unsigned_abs() * EDGES_PER_DETENT {
                levels = if detents > 0 {
                    levels.next_forward()
                } else {
                    levels.next_reverse()
                };
                edge(levels);
            }
        }
        Command::Ab(bits) => edge(AbLevels::from_bits(bits)),
        Command::Axis(axis) => sim::set_axis_mask(axis.active_mask()),
        Command::Mult(multiplier) => sim::set_multiplier_mask(multiplier.active_mask()),
        Command::Stall(ms) => stall(ms),
    }
    Ok(())
}

/// Sets the wheel's levels and runs the EXTI9_5 task on them, as a pin change would.
fn edge(levels: AbLevels) {
    sim::set_ab(levels);
    rtic::pend(Interrupt::EXTI9_5);
    cortex_m::asm::isb();
    // The EXTI task outranks this one and runs right after the `isb`; should the emulator
    // deliver it late, wait, so that no two edges merge into one read.
    while NVIC::is_pending(Interrupt::EXTI9_5) {}
}
