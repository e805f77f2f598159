"""Unit tests of the cycle classifier, on real Thumb-2 encodings (as the firmware has them)."""

import unittest

from capstone import arm

import cycles


def decode(hex_bytes: str, address: int = 0x0800_0100):
    md = cycles.disassembler()
    insn = next(md.disasm(bytes.fromhex(hex_bytes), address))
    return insn, cycles.classify(insn)


class ClassifyTest(unittest.TestCase):
    def test_data_processing_is_one_cycle(self):
        for code, mnemonic in [
            ("02af", "add"),  # add r7, sp, #8
            ("c021", "movs"),  # movs r1, #0xc0
            ("40f21440", "movw"),  # movw r0, #0x414
            ("d2b2", "uxtb"),  # uxtb r2, r2
        ]:
            insn, timing = decode(code)
            self.assertEqual(insn.mnemonic, mnemonic)
            self.assertEqual((timing.kind, timing.cycles, timing.taken), (cycles.ALU, 1, 0))

    def test_push_and_pop(self):
        _, push = decode("b0b5")  # push {r4, r5, r7, lr}
        self.assertEqual((push.kind, push.cycles, push.taken), (cycles.MULTIPLE, 5, 0))
        self.assertTrue(push.writes_sp)
        _, pop = decode("b0bd")  # pop {r4, r5, r7, pc}
        self.assertEqual((pop.kind, pop.cycles, pop.taken), (cycles.BRANCH, 5, 3))

    def test_loads_and_stores_pipeline(self):
        _, store = decode("0160")  # str r1, [r0]
        self.assertEqual((store.kind, store.cycles, store.pipelined), (cycles.STORE, 2, 1))
        _, load = decode("0268")  # ldr r2, [r0]
        self.assertEqual((load.kind, load.cycles, load.pipelined), (cycles.LOAD, 2, 1))
        self.assertEqual(load.loaded_regs, (arm.ARM_REG_R2,))
        self.assertEqual(load.address_regs, (arm.ARM_REG_R0,))

    def test_system_and_barriers(self):
        insn, mrs = decode("eff31184")  # mrs r4, basepri
        self.assertEqual(insn.mnemonic, "mrs")
        self.assertEqual((mrs.kind, mrs.cycles), (cycles.SYSTEM, 2))
        _, isb = decode("bff36f8f")  # isb sy
        self.assertEqual((isb.cycles, isb.flushes), (4, True))
        _, dmb = decode("bff35f8f")  # dmb sy
        self.assertEqual((dmb.cycles, dmb.flushes), (2, False))

    def test_branches(self):
        _, tbb = decode("dfe803f0")  # tbb [pc, r3]
        self.assertEqual((tbb.kind, tbb.cycles, tbb.taken), (cycles.BRANCH, 2, 2))
        _, blx = decode("8847")  # blx r1
        self.assertEqual((blx.cycles, blx.taken), (1, 3))
        insn, bne = decode("01d1")  # bne +2
        self.assertEqual(insn.cc, arm.ARM_CC_NE)
        self.assertEqual((bne.cycles, bne.taken), (1, 2))

    def test_multiply_and_divide(self):
        _, mla = decode("03fb0215")  # mla r5, r3, r2, r1
        self.assertEqual(mla.cycles, 2)
        _, muls = decode("5a43")  # muls r2, r3, r2
        self.assertEqual(muls.cycles, 1)
        _, udiv = decode("b0fbf1f0")  # udiv r0, r0, r1
        self.assertEqual(udiv.cycles, 12)


class CounterTest(unittest.TestCase):
    def test_sequence_with_pipelining_and_a_taken_branch(self):
        counter = cycles.CycleCounter()
        _, load = decode("0268")  # ldr r2, [r0]      2
        _, store = decode("0160")  # str r1, [r0]     1 (pipelined)
        _, bne = decode("01d1")  # bne                 1 + 2 taken
        _, alu = decode("c021")  # movs r1, #0xc0     1
        counter.step(load, 0x100, 2)
        counter.step(store, 0x102, 2)
        counter.step(bne, 0x104, 2)
        counter.step(alu, 0x120, 2)  # not 0x106: the branch was taken
        counter.finish(0x122)
        self.assertEqual(counter.instructions, 4)
        self.assertEqual(counter.cycles, 2 + 1 + 3 + 1)
        self.assertEqual(counter.refetches, 1)
        self.assertEqual(
            counter.by_kind, {cycles.LOAD: 1, cycles.STORE: 1, cycles.BRANCH: 1, cycles.ALU: 1}
        )

    def test_untaken_branch_and_dependent_load(self):
        counter = cycles.CycleCounter()
        _, load = decode("0268")  # ldr r2, [r0]
        _, dependent = decode("1168")  # ldr r1, [r2]: its address is the previous result
        _, bne = decode("01d1")
        counter.step(load, 0x100, 2)
        counter.step(dependent, 0x102, 2)
        counter.step(bne, 0x104, 2)
        counter.finish(0x106)  # fell through
        self.assertEqual(counter.cycles, 2 + 2 + 1)
        self.assertEqual(counter.refetches, 0)

    def test_failed_condition_costs_one_cycle(self):
        counter = cycles.CycleCounter()
        _, load = decode("0268")
        counter.step(load, 0x100, 2, passed=False)
        self.assertEqual(counter.cycles, 1)

    def test_return_is_a_taken_branch(self):
        counter = cycles.CycleCounter()
        _, pop = decode("b0bd")
        counter.step(pop, 0x100, 2)
        counter.finish(0x0001_0000)
        self.assertEqual(counter.cycles, 5 + 3)


class ConditionTest(unittest.TestCase):
    def test_flags(self):
        z = 1 << 30
        n = 1 << 31
        v = 1 << 28
        self.assertTrue(cycles.condition_passes(arm.ARM_CC_EQ, z))
        self.assertFalse(cycles.condition_passes(arm.ARM_CC_NE, z))
        self.assertTrue(cycles.condition_passes(arm.ARM_CC_LT, n))
        self.assertFalse(cycles.condition_passes(arm.ARM_CC_LT, n | v))
        self.assertTrue(cycles.condition_passes(arm.ARM_CC_GE, n | v))
        self.assertTrue(cycles.condition_passes(arm.ARM_CC_LE, z))
        self.assertTrue(cycles.condition_passes(arm.ARM_CC_AL, 0))


if __name__ == "__main__":
    unittest.main()
