//! The QEMU board variant (`--features qemu`): the same RTIC application on
//! `qemu-system-arm -M stm32vldiscovery` (an STM32F100 with 8 KiB RAM), with the hardware the
//! emulator lacks replaced by two serial transports.
//!
//! QEMU models the CPU, NVIC, SysTick (24 MHz whatever RCC says) and the USARTs; RCC, GPIO,
//! AFIO, EXTI and timers are stubs that read 0, and bxCAN is not mapped at all. So only the
//! board layer differs from the STM32F103 build:
//!
//! - [`board`]: `init` (HSI clock only, both USARTs), simulated wheel and selector inputs, LED
//!   and watchdog stand-ins, `SYSCLK_HZ` = 24 MHz for the SysTick monotonic, the boot-up
//!   delay, and the USART halves the app's QEMU tasks own (`board::Own`).
//! - [`slcan_port`]: the [`CanPort`](crate::can::CanPort) over SLCAN (Lawicel) on USART1,
//!   with the methods the CAN tasks call on the bxCAN port.
//! - [`stimulus`]: the test command line on USART2 that turns the simulated wheel (edge by
//!   edge through the EXTI9_5 task) and sets the simulated switch lines.
//! - [`storage`]: the parameter pages in RAM (the board's `ParameterPage` over 2 KiB of RAM).
//! - [`sim`]: the simulated input lines shared by `stimulus` and `board`.
//! - [`usart`]: the few USART registers the transports need.
//!
//! The byte-level protocols are in the host-tested `sim-io` crate; this module only moves
//! bytes between the USARTs and it. The defmt log goes out over semihosting.

// The feature picks the variant in the app (`src/main.rs`); both layers always build.
#[cfg(all(feature = "board", feature = "qemu"))]
compile_error!(
    "features `board` and `qemu` exclude each other: build the QEMU variant with \
     `--no-default-features --features qemu` (`cargo xtask qemu` does)"
);
#[cfg(not(any(feature = "board", feature = "qemu")))]
compile_error!("enable one board variant: feature `board` (default) or `qemu`");

pub mod board;
pub mod sim;
pub mod slcan_port;
pub mod stimulus;
pub mod storage;
pub mod usart;

/// The board layer of the variant being built, chosen here so that the app names no
/// feature to import it: the STM32F103's [`crate::board`], or with `--features qemu` this
/// variant's [`board`].
pub mod chosen {
    #[cfg(feature = "qemu")]
    pub use super::board;
    #[cfg(not(feature = "qemu"))]
    pub use crate::board;
}

// The variant's defmt transport: linked from here, the app does not name it.
#[cfg(feature = "qemu")]
use defmt_semihosting as _;
