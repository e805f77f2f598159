"""One emulated STM32F103 (the Blue Pill) for every tool that runs the release image.

- `image`: the ELF loader and the memory map from the linker script (the root `memory.x`);
- `cortex`: the Cortex-M3 core around unicorn: the NVIC (nesting, tail-chaining,
  BASEPRI/PRIMASK), SysTick, the exception entry and return, and a precise mode that takes
  an exception at the exact instruction boundary and charges each instruction a cost;
- `periph`: RCC, GPIO/AFIO/EXTI, IWDG, the flash controller and bxCAN as RM0008 and PM0075
  describe them;
- `machine`: the board: memory map, peripherals, the handwheel's pins, the host's side of
  the CAN bus, resets and emulated time.

`tools/board-emu` paces the machine in real time behind TCP ports; `tools/machine-bench`
runs it in precise mode with a cycle estimate per instruction. Each behaviour has its
section of RM0008, PM0056, PM0075 or the ARMv7-M ARM beside it and a unit test (`test_*.py`,
pytest; the tests that boot the release image read it from HANDWHEEL_BOARD_ELF, else
target/).
"""
