"""Unit tests of the peripheral register model."""

import unittest

import stm32


class Model:
    def __init__(self):
        self.pended = []
        self.sent = []
        self.p = stm32.Peripherals(self._pend, lambda box, frame: self.sent.append((box, frame)))

    def _pend(self, exception):
        self.pended.append(exception)
        self.p.pending.add(exception)


class RegisterTest(unittest.TestCase):
    def test_plain_registers_read_back_with_byte_lanes(self):
        m = Model()
        m.p.write(0x4001_0000, 4, 0x1234_5678)
        self.assertEqual(m.p.read(0x4001_0000, 4), 0x1234_5678)
        m.p.write(0x4001_0002, 1, 0xAB)
        self.assertEqual(m.p.read(0x4001_0000, 4), 0x12AB_5678)
        self.assertEqual(m.p.read(0x4001_0001, 2), 0xAB56)

    def test_rcc_ready_flags_and_clock_switch(self):
        m = Model()
        self.assertEqual(m.p.read(stm32.RCC, 4) & 0b11, 0b11)  # HSI on and ready at reset
        m.p.write(stm32.RCC, 4, (1 << 16) | (1 << 24))
        self.assertEqual(m.p.read(stm32.RCC, 4) & ((1 << 17) | (1 << 25)), (1 << 17) | (1 << 25))
        m.p.write(stm32.RCC + 4, 4, 0b10)  # SW = PLL
        self.assertEqual((m.p.read(stm32.RCC + 4, 4) >> 2) & 3, 0b10)

    def test_gpio_inputs_and_outputs(self):
        m = Model()
        m.p.pins.ports[stm32.GPIOB] = 0xFF3F
        self.assertEqual(m.p.read(stm32.GPIOB + 0x08, 4), 0xFF3F)
        m.p.write(stm32.GPIOC + 0x10, 4, 1 << 13)  # BSRR set
        self.assertEqual(m.p.read(stm32.GPIOC + 0x0C, 4), 1 << 13)
        m.p.write(stm32.GPIOC + 0x10, 4, 1 << 29)  # BSRR reset
        self.assertEqual(m.p.read(stm32.GPIOC + 0x0C, 4), 0)

    def test_exti_pending_is_write_one_to_clear(self):
        m = Model()
        m.p.set_exti_pending(0xC0)
        m.p.write(stm32.EXTI + 0x14, 4, 0x40)
        self.assertEqual(m.p.read(stm32.EXTI + 0x14, 4), 0x80)

    def test_bitband_alias(self):
        # RCC_APB1ENR (0x4002101C) bit 25 (CAN).
        offset = (0x2101C * 32) + 25 * 4
        self.assertEqual(stm32.bitband_target(offset), (0x4002_101F, 1))


class CanTest(unittest.TestCase):
    def test_init_mode_handshake(self):
        m = Model()
        self.assertEqual(m.p.read(stm32.CAN_MSR, 4) & 3, 0b10)  # asleep after reset
        m.p.write(stm32.CAN_MCR, 4, 1)  # INRQ, SLEEP cleared
        self.assertEqual(m.p.read(stm32.CAN_MSR, 4) & 3, 0b01)
        m.p.write(stm32.CAN_MCR, 4, 0)
        self.assertEqual(m.p.read(stm32.CAN_MSR, 4) & 3, 0b00)

    def test_receive_fifo(self):
        m = Model()
        m.p.write(stm32.CAN_IER, 4, 0b10)  # FMPIE0
        m.p.receive(stm32.CanFrame(0x610, bytes([0x40, 0x00, 0x10, 0x00])))
        self.assertEqual(m.pended, [16 + stm32.IRQ_CAN_RX0])
        self.assertEqual(m.p.read(stm32.CAN_RF0R, 4) & 3, 1)
        self.assertEqual(m.p.read(stm32.CAN_RX_FIFO0, 4) >> 21, 0x610)
        self.assertEqual(m.p.read(stm32.CAN_RX_FIFO0 + 4, 4) & 0xF, 4)
        self.assertEqual(m.p.read(stm32.CAN_RX_FIFO0 + 8, 4), 0x0010_0040)
        m.p.write(stm32.CAN_RF0R, 4, 1 << 5)  # RFOM0
        self.assertEqual(m.p.read(stm32.CAN_RF0R, 4) & 3, 0)

    def test_transmit_and_complete(self):
        m = Model()
        m.p.write(stm32.CAN_IER, 4, 1)  # TMEIE
        self.assertEqual(m.p.read(stm32.CAN_TSR, 4) >> 24 & 3, 0)  # CODE: mailbox 0 free
        base = stm32.CAN_TX_MAILBOX
        m.p.write(base + 4, 4, 2)  # DLC 2
        m.p.write(base + 8, 4, 0x0000_0560)
        m.p.write(base, 4, (0x590 << 21) | 1)  # TXRQ
        self.assertEqual(m.sent, [(0, stm32.CanFrame(0x590, bytes([0x60, 0x05])))])
        tsr = m.p.read(stm32.CAN_TSR, 4)
        self.assertEqual(tsr & (1 << 26), 0)  # mailbox 0 pending
        self.assertEqual(tsr >> 24 & 3, 1)  # next free: 1
        self.assertEqual(m.p.complete_transmissions(), 1)
        self.assertEqual(m.pended, [16 + stm32.IRQ_CAN_TX])
        tsr = m.p.read(stm32.CAN_TSR, 4)
        self.assertEqual(tsr & 0b11, 0b11)  # RQCP0, TXOK0
        m.p.write(stm32.CAN_TSR, 4, 1)  # clear RQCP0
        self.assertEqual(m.p.read(stm32.CAN_TSR, 4) & 0xF, 0)

    def test_error_state_raises_sce(self):
        m = Model()
        m.p.write(stm32.CAN_IER, 4, 1 << 15)
        m.p.set_error_state(0b010)
        self.assertEqual(m.pended, [16 + stm32.IRQ_CAN_SCE])
        self.assertEqual(m.p.read(stm32.CAN_ESR, 4), 0b010)
        m.p.write(stm32.CAN_MSR, 4, 1 << 2)  # ERRI cleared
        self.assertEqual(m.p.read(stm32.CAN_MSR, 4) & 0x4, 0)


class NvicTest(unittest.TestCase):
    def test_pend_paths_and_priorities(self):
        m = Model()
        m.p.write(stm32.NVIC_ISPR, 4, 1 << 29)  # TIM3
        m.p.write(stm32.NVIC_STIR, 4, 28)  # TIM2
        m.p.write(stm32.SCB_ICSR, 4, 1 << 26)  # PENDSTSET
        self.assertEqual(m.pended, [45, 44, 15])
        self.assertEqual(m.p.read(stm32.NVIC_ISPR, 4), (1 << 28) | (1 << 29))
        m.p.write(stm32.NVIC_ICPR, 4, 1 << 28)
        self.assertEqual(m.p.pending, {45, 15})
        m.p.write(stm32.NVIC_IPR + 29, 1, 0xE0)
        self.assertEqual(m.p.priority(45), 0xE0)
        self.assertEqual(m.p.priority(15), 0)
        self.assertFalse(m.p.enabled(45))
        m.p.write(stm32.NVIC_ISER, 4, 1 << 29)
        self.assertTrue(m.p.enabled(45))
        m.p.write(stm32.NVIC_ICER, 4, 1 << 29)
        self.assertFalse(m.p.enabled(45))

    def test_systick_countflag_clears_on_read(self):
        m = Model()
        m.p.write(stm32.SYST_CSR, 4, 0b111)
        m.p.tick()
        self.assertEqual(m.pended, [15])
        self.assertTrue(m.p.enabled(15))
        self.assertEqual(m.p.read(stm32.SYST_CSR, 4), (1 << 16) | 0b111)
        self.assertEqual(m.p.read(stm32.SYST_CSR, 4), 0b111)


if __name__ == "__main__":
    unittest.main()
