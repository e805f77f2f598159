//! The clock tree both images run on: HSE 8 MHz, PLL x9, AHB /1, APB1 /2, APB2 /1, two flash
//! wait states (RM0008 7.3, 3.3.3).

/// The crystal on the board.
pub const HSE_HZ: u32 = 8_000_000;
/// Core clock (PLL x9), also the SysTick clock.
pub const SYSCLK_HZ: u32 = 72_000_000;
/// APB1 clock (its maximum): the bxCAN kernel clock that the bit timing table assumes.
pub const APB1_HZ: u32 = 36_000_000;
/// APB2 clock.
pub const APB2_HZ: u32 = SYSCLK_HZ;

const _: () = assert!(HSE_HZ * 9 == SYSCLK_HZ && SYSCLK_HZ / 2 == APB1_HZ);

/// Freezes the clock tree above (the HAL's `rcc::Config`, which also sets the flash wait
/// states through `acr`).
#[cfg(target_os = "none")]
pub fn freeze(
    rcc: stm32f1xx_hal::pac::RCC,
    acr: &mut stm32f1xx_hal::flash::ACR,
) -> stm32f1xx_hal::rcc::Rcc {
    use stm32f1xx_hal::prelude::*;
    rcc.freeze(
        stm32f1xx_hal::rcc::Config::hse(HSE_HZ.Hz())
            .sysclk(SYSCLK_HZ.Hz())
            .hclk(SYSCLK_HZ.Hz())
            .pclk1(APB1_HZ.Hz())
            .pclk2(APB2_HZ.Hz()),
        acr,
    )
}

/// The pull-ups need a moment to lift open lines after a pin's mode change: cycles to wait
/// before reading the DIP switch (100 us).
pub const PULL_UP_SETTLE_CYCLES: u32 = SYSCLK_HZ / 10_000;
