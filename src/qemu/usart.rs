//! The USART registers the QEMU transports use: enable, receive a byte, send bytes.
//!
//! QEMU's STM32 USART ignores the baud rate and the pins (GPIO and AFIO are stubs there), and
//! drops received bytes until CR1 has UE and RE set, so [`Usart::new`] enables it at once.
//! Transmission is immediate in the emulator (TXE is always set), so writes are blocking.

use core::ops::Deref;

use crate::pac::usart1::RegisterBlock;

/// One USART, owned, both directions.
pub struct Usart<U> {
    regs: U,
}

impl<U: Deref<Target = RegisterBlock>> Usart<U> {
    /// Enables the USART: transmitter, receiver, and the receive interrupt (RXNE).
    pub fn new(regs: U) -> Self {
        regs.cr1().write(|w| {
            w.ue().set_bit();
            w.te().set_bit();
            w.re().set_bit();
            w.rxneie().set_bit()
        });
        Self { regs }
    }

    /// The next received byte, if one is waiting (reading it clears RXNE and the interrupt).
    #[inline]
    pub fn read(&mut self) -> Option<u8> {
        read(&self.regs)
    }

    /// Sends `bytes`, waiting for TXE before each one.
    pub fn write_all(&mut self, bytes: &[u8]) {
        write_all(&self.regs, bytes);
    }

    /// Splits into a receiving and a transmitting half, for two owners (an interrupt handler
    /// and a task). `second` is another handle of the same USART: the halves use disjoint
    /// data registers (the receiver reads DR's receive side, the transmitter writes its
    /// transmit side) and only read SR besides.
    pub fn split(self, second: U) -> (UsartRx<U>, UsartTx<U>) {
        (UsartRx { regs: self.regs }, UsartTx { regs: second })
    }
}

/// The receiving half of a [`Usart`].
pub struct UsartRx<U> {
    regs: U,
}

impl<U: Deref<Target = RegisterBlock>> UsartRx<U> {
    /// The next received byte, if one is waiting (reading it clears RXNE and the interrupt).
    #[inline]
    pub fn read(&mut self) -> Option<u8> {
        read(&self.regs)
    }
}

/// The transmitting half of a [`Usart`].
pub struct UsartTx<U> {
    regs: U,
}

impl<U: Deref<Target = RegisterBlock>> UsartTx<U> {
    /// Sends `bytes`, waiting for TXE before each one.
    pub fn write_all(&mut self, bytes: &[u8]) {
        write_all(&self.regs, bytes);
    }
}

#[inline]
fn read(regs: &RegisterBlock) -> Option<u8> {
    if regs.sr().read().rxne().bit_is_set() {
        // 8 data bits: the 9th DR bit is unused.
        Some(regs.dr().read().dr().bits() as u8)
    } else {
        None
    }
}

fn write_all(regs: &RegisterBlock, bytes: &[u8]) {
    for &byte in bytes {
        while regs.sr().read().txe().bit_is_clear() {}
        regs.dr().write(|w| w.dr().set(u16::from(byte)));
    }
}
