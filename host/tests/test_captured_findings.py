"""The hostile runs' findings as regression tests of the core: captures the interop suite took
of the component against the firmware on the emulated board (`tests/interop/test_copies.py`,
its findings 1-5 and the trickling bus; `tests/interop/test_host_component.py`, the frozen
component), each with its host notes and the component's pin log (fake_hal's), in `captures/`.
Replayed through today's core, every one must end on the pins the component wrote then, and
show what its finding is about.

To take them again (after a change of the rule that changes what the pins do), run
`cargo xtask interop -k "test_copies or test_host_component" --basetemp DIR` and copy each
test's `capture.log` (gzip -9 -n), `capture.log.host` and `hal.log` (gzip -9 -n) from
`DIR/<test>0/` to `captures/<name>.log.gz`, `<name>.log.gz.host` and `<name>.hal.gz`."""

import gzip
from pathlib import Path

import pytest

from canopen_handwheel import capture, decode

CAPTURES = Path(__file__).resolve().parent / "captures"
FINDINGS = (
    "copies_of_any_age",  # test_copies.py, finding 1
    "y_record_255_back",  # finding 2
    "lost_boot_up",  # finding 3
    "quick_power_cycle",  # finding 4
    "blocked_transmit_path",  # finding 5
    "trickling_bus",
    "frozen_component",  # test_host_component.py
)


def replayed(name: str):
    """(the replay of capture `name`, the live pin changes)."""
    r = decode.replay([capture.read(CAPTURES / f"{name}.log.gz")])
    live = []
    with gzip.open(CAPTURES / f"{name}.hal.gz", "rt") as f:
        for line in f:
            t, pin, value = line.split()
            live.append((float(t), pin, value))
    return r, live


def verdicts(r, kind=None):
    return [
        line.verdict
        for line in r.lines
        if line.verdict is not None and (kind is None or line.verdict.kind == kind)
    ]


@pytest.mark.parametrize("name", FINDINGS)
def test_the_capture_replays_to_the_live_pins(name):
    r, live = replayed(name)
    assert r.notes and not r.mismatches, r.mismatches
    assert r.differences(live) == []
    records = [line for line in r.lines if line.frame.id == 0x190]
    assert records and all(line.verdict is not None for line in records)


def test_copies_of_any_age_move_nothing():
    """Finding 1: the ten copies (1000, 129, ... 512 records back) are copies, each counted
    bad and credited nothing; X never steps back."""
    r, _ = replayed("copies_of_any_age")
    copies = verdicts(r, decode.COPY)
    assert len(copies) == 10 and not any(v.credited for v in copies)
    assert r.pins["frames-bad"] == 10
    x = r.history("axis.x.jog-counts")
    assert x == sorted(x) and x[-1] == r.pins["axis.x.jog-counts"] > 0


def test_an_old_y_record_never_moves_y():
    """Finding 2: the five copies of Y records 253..257 back, sent while X is selected, are
    copies; Y keeps the 3 detents turned on it."""
    r, _ = replayed("y_record_255_back")
    copies = verdicts(r, decode.COPY)
    assert len(copies) == 5 and not any(v.credited for v in copies)
    assert r.history("axis.y.jog-counts") == [1, 2, 3]


def test_a_device_restarted_unseen_is_configured_before_the_feed():
    """Finding 3: after the power cycle whose boot-up the relay dropped, the records of no
    session make the host check its configuration, which finds the device without it and
    writes a new session, before the feed is enabled again; nothing is credited from the
    records of no session meanwhile."""
    r, _ = replayed("lost_boot_up")
    events = [e for _, e in sorted(r.events)]
    configured = [i for i, e in enumerate(events) if ": done, session" in e]
    assert events[configured[-1]] == "check: done, session 2 (0x2002 was 0)"
    enabled = [i for i, e in enumerate(events) if e.startswith("feed 1: done")]
    assert len(configured) == 2 and len(enabled) == 2
    assert configured[1] < enabled[1]
    assert not any(v.credited for v in verdicts(r, decode.FOREIGN))


def test_a_quick_power_cycle_counts_nothing_bad():
    """Finding 4: the new life's records are judged against the new session, not as copies
    of the old one's: nothing counted bad, every detent after the feed came back credited."""
    r, _ = replayed("quick_power_cycle")
    assert r.pins["frames-bad"] == 0
    assert not verdicts(r, decode.COPY) and not verdicts(r, decode.IMPOSSIBLE)
    assert sum(v.delta for v in verdicts(r) if v.axis == "x") == r.pins["axis.x.jog-counts"]


def test_a_blocked_transmit_path_is_reported_as_such():
    """Finding 5: the stop after the held bus is reported with its reason, the transmit
    path (stop-reason 2)."""
    r, _ = replayed("blocked_transmit_path")
    assert (r.pins["feed-stops"], r.pins["stop-reason"]) == (1, 2)
    logged = [entry for line in r.lines for entry in line.log]
    assert "feed stopped by the device: transmit path blocked (EMCY 0x8100)" in logged


def test_a_trickling_bus_credits_nothing_late():
    """The trickling bus: of the 20 detents turned while one frame per 95 ms got out, at most
    3 are credited."""
    r, _ = replayed("trickling_bus")
    credited = [v for v in verdicts(r) if v.credited]
    assert len(credited) <= 1 + 3
    assert r.pins["stop-reason"] == 2


def test_a_frozen_components_backlog_moves_nothing():
    """The records that waited while the component was stopped are baselines from a backlog;
    only the detents turned before and after move X."""
    r, _ = replayed("frozen_component")
    backlog = [v for v in verdicts(r, decode.BASELINE) if "from a backlog" in v.text]
    assert backlog and not any(v.credited for v in backlog)
    assert r.pins["axis.x.jog-counts"] == 5
