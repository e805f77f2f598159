//! What the chip itself holds: the 96-bit unique ID (RM0008 30.2).

/// Address of the 96-bit unique device ID (RM0008, "Unique device ID register").
const UNIQUE_ID_ADDRESS: usize = 0x1FFF_F7E8;

/// The MCU's 96-bit unique ID as three words, lowest address first (the serial number's
/// source in both images).
///
/// Read by hand: the HAL has no API for the unique ID.
#[must_use]
pub fn unique_id() -> [u32; 3] {
    let base = UNIQUE_ID_ADDRESS as *const u32;
    core::array::from_fn(|word| {
        // SAFETY: the unique ID is factory-programmed system memory at a fixed, word-aligned
        // address on every STM32F1; `word` < 3 keeps the read inside its 12 bytes, and the
        // read has no side effects.
        unsafe { core::ptr::read_volatile(base.add(word)) }
    })
}
