"""The benchmark's edges made at the wheel's worst moments, on the release image (as
test_probe.py): an edge made as a critical section that holds the wheel off starts waits for
its end, and the edge's own lock makes no edge."""

import pytest

import bench
from stm32emu.test_machine import ELF

pytestmark = pytest.mark.skipif(not ELF.exists(), reason=f"no release image at {ELF}")


def test_an_edge_made_as_primask_is_raised_waits_for_the_whole_critical_section():
    """The bus-error scenario's log frames: an edge made as each critical section that holds
    the wheel off starts is read only after it, so the worst measured wait covers the
    longest such stretch (entry and the handler up to its read on top)."""
    rig = bench.Rig(str(ELF))
    rig.armed = {"held"}
    rig.m.can.inject(16, 0, rig.m.now)
    rig.m.update_irqs()
    rig.settle("bus error")
    rig.tick(12, "bus error")
    assert rig.injected is None
    masked, _, where, _ = rig.p.longest_masks[rig.wheel_priority]
    primask = {k: v for k, v in rig.latencies.items() if k.startswith("PRIMASK is raised in")}
    assert primask, rig.latencies
    worst = max(wait for wait, _ in primask.values())
    assert masked > 500, where  # a defmt log frame under the critical section
    assert masked + bench.cycles.EXCEPTION_ENTRY < worst < masked + 100, (worst, masked)
    assert not any(k.startswith("BASEPRI") for k in rig.latencies), "BASEPRI holds no edge off"


def test_the_edges_own_lock_makes_no_edge(monkeypatch):
    """With every critical section armed, the edge handler's own (its lock of the shared
    wheel state) is left out: an edge made there would be followed by another for ever."""
    monkeypatch.setattr(bench, "STEP_LIMIT_MS", 5)
    rig = bench.Rig(str(ELF))
    mark = len(rig.p.invocations)
    rig.armed = {"mask"}
    for _ in range(8):
        rig.step(1, "steps")
    assert rig.injected is None
    assert not any("EXTI9_5" in cause for cause in rig.latencies), rig.latencies
    made = sum(count for _, count in rig.latencies.values())
    edges = [i for i in rig.p.invocations[mark:] if i.exception == rig.exti]
    assert len(edges) == 8 + made, "one run per step and per edge made elsewhere"
