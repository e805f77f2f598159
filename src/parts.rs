//! What a board hands the application: one [`Board`] for both variants, over the variant's
//! part types ([`BoardParts`]), so that a part one variant forgets does not compile.

/// The types of a board variant's parts.
pub trait BoardParts {
    /// Wheel A/B inputs, handed to the edge interrupt.
    type Wheel;
    /// The axis and multiplier switch lines.
    type Selectors: handwheel_core::SelectorInput;
    /// The RUN and ERR LEDs.
    type Leds;
    /// The CAN controller (or its stand-in), not yet started.
    type Can;
    /// Where 0x1010 stores parameters.
    type Storage;
    /// The independent watchdog (or its stand-in), not yet started.
    type Watchdog;
    /// Why the MCU last reset.
    type ResetCause: defmt::Format;
    /// What only the variant's own interrupt tasks use: nothing on the board, the USART
    /// lines under QEMU.
    type Own;
}

/// Everything a variant's `init` sets up for the application.
pub struct Board<P: BoardParts> {
    /// Wheel A/B inputs.
    pub wheel: P::Wheel,
    /// Axis and multiplier switch lines.
    pub selectors: P::Selectors,
    /// DIP switch, read once at start-up: bit `i` set = switch `i + 1` on.
    pub dip: u8,
    /// RUN and ERR LEDs.
    pub leds: P::Leds,
    /// The CAN controller, not yet started.
    pub can: P::Can,
    /// The parameter storage.
    pub storage: P::Storage,
    /// The watchdog, not started yet.
    pub watchdog: P::Watchdog,
    /// Why the MCU last reset.
    pub reset_cause: P::ResetCause,
    /// The MCU's 96-bit unique ID (a fixed stand-in under QEMU).
    pub unique_id: [u32; 3],
    /// The variant's own parts.
    pub own: P::Own,
}

/// Declares a variant's part types: `board_parts!(Parts: wheel, selectors, leds, can,
/// storage, watchdog, reset cause, own)`, the types in [`BoardParts`]' order.
macro_rules! board_parts {
    ($parts:ident: $wheel:ty, $selectors:ty, $leds:ty, $can:ty, $storage:ty, $watchdog:ty, $reset:ty, $own:ty) => {
        impl $crate::parts::BoardParts for $parts {
            type Wheel = $wheel;
            type Selectors = $selectors;
            type Leds = $leds;
            type Can = $can;
            type Storage = $storage;
            type Watchdog = $watchdog;
            type ResetCause = $reset;
            type Own = $own;
        }
    };
}
pub(crate) use board_parts;
