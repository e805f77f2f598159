"""The component's rule against the model checker's: every record stream in the vectors that
`crates/feed-check` writes (`feed-check --vectors FILE`, run by `cargo xtask test`, which sets
HANDWHEEL_FEED_VECTORS) is replayed through `core.replay`, and the per-axis counts must be
exactly what the checker's rule credited for it. The checker proves its rule safe against the
real device code; this keeps `core.py` the same rule. Since feed record v2 a stream holds the
configurations its host made (("configure", found, t): `core.replay_core`), so that its
records carry the session the core wrote; the tokens must be the ones `core.free_tokens` and
`core.pick_token` choose. Besides the model's random walks, the vectors hold streams at each
limit of the rule, met and missed by one (`crates/feed-check/src/boundaries.rs`). The streams
of a setting whose rule dates records (`"dating": true`: a path that holds the device's frames
upstream of the host, the sequence probe) hold the core's probes (("probe", nonce, floor, t)
and ("probed", value, t): `core.replay_core`) and replay with `Config(dating=True)`."""

import json
import os
import sys
from pathlib import Path

import pytest

from canopen_handwheel import core

VECTORS = os.environ.get("HANDWHEEL_FEED_VECTORS")


def load():
    lines = Path(VECTORS).read_text().splitlines() if VECTORS else []
    return [json.loads(line) for line in lines if line.strip()]


def replay(v) -> dict:
    """The counts `core.replay` credits for vector `v`, with the dating its setting has."""
    cfg = core.Config(axes="xy", dating=bool(v.get("dating", False)))
    return core.replay([tuple(e) for e in v["events"]], cfg)


@pytest.mark.skipif(not VECTORS, reason="HANDWHEEL_FEED_VECTORS not set (cargo xtask test sets it)")
def test_core_credits_exactly_what_the_checked_rule_credits():
    vectors = load()
    assert len(vectors) >= 1000, "the checker wrote its vectors"
    moved = 0
    for n, v in enumerate(vectors):
        counts = replay(v)
        want = v["counts"]
        assert (counts["x"], counts["y"]) == (want["x"], want["y"]), (n, v["name"])
        moved += bool(want["x"] or want["y"])
    # The vectors must exercise crediting, not only silence.
    assert moved >= len(vectors) // 4
    # And every limit of the rule met exactly and missed by one (`boundaries.rs`).
    boundaries = [v["name"] for v in vectors if v["name"].startswith("boundary:")]
    assert len(boundaries) >= 21, boundaries


@pytest.mark.skipif(not VECTORS, reason="HANDWHEEL_FEED_VECTORS not set (cargo xtask test sets it)")
def test_the_dating_vectors_probe_hold_and_credit():
    """The streams with dating reach what the dating is for: probes answered, frames held
    and released (a probe's answer arriving after a later one was due), and credits."""
    dating = [v for v in load() if v.get("dating")]
    assert len(dating) >= 100, "the checker wrote the dating setting's streams"
    probed = [v for v in dating if any(e[0] == "probed" for e in v["events"])]
    moved = [v for v in dating if v["counts"]["x"] or v["counts"]["y"]]
    assert len(probed) == len(dating), "every stream probes"
    assert len(moved) >= len(dating) // 4


@pytest.mark.skipif(not VECTORS, reason="HANDWHEEL_FEED_VECTORS not set (cargo xtask test sets it)")
@pytest.mark.parametrize("mutant", ["date limit x10", "sent_at at the answer"])
def test_the_dating_vectors_notice_a_changed_dating(monkeypatch, mutant):
    """The dating streams tell the core's dating from changes the checker's mutants make."""
    dating = [v for v in load() if v.get("dating")]
    assert _differs(dating) == [], "the rule as shipped agrees"
    if mutant == "date limit x10":
        _patch(monkeypatch, "DATE_LIMIT", lambda v: v * 10)
    elif mutant == "sent_at at the answer":
        done = core.Core.done

        def late_done(c, action, ok, abort, now, result=None):
            if isinstance(result, core.Probed) and result.sent_at is not None:
                result = core.Probed(now, result.value)
            done(c, action, ok, abort, now, result)

        monkeypatch.setattr(core.Core, "done", late_done)
    assert _differs(dating), f"no dating vector notices {mutant}"


def _patch(monkeypatch, name, change):
    """`name` changed by `change` in every module of the core that holds it: its home and
    each module that imported it (the core's modules read their own copies)."""
    home = next(
        m
        for key, m in sorted(sys.modules.items())
        if key.startswith("canopen_handwheel.") and name in vars(m) and m is not core
    )
    value = change(getattr(home, name))
    for key, module in list(sys.modules.items()):
        if key.startswith("canopen_handwheel.") and name in vars(module):
            monkeypatch.setattr(module, name, value)


def _differs(vectors) -> list:
    """The names of the vectors whose replay now credits other counts."""
    differ = []
    for v in vectors:
        counts = replay(v)
        if (counts["x"], counts["y"]) != (v["counts"]["x"], v["counts"]["y"]):
            differ.append(v["name"])
    return differ


# Single changes of the rule that the boundary vectors must notice: a limit moved by one
# unit (a number, a millisecond) or a comparison off by one.
RULE_MUTANTS = {
    "burst + 1": ("SEQUENCE_BURST", lambda v: v + 1),
    "in transit + 1 ms": ("_IN_TRANSIT_US", lambda v: v + 1000),
    "order window + 1 ms": ("ORDER_WINDOW", lambda v: v + 0.001),
    "order window - 1 ms": ("ORDER_WINDOW", lambda v: v - 0.001),
    "same-epoch gap + 1": ("SAME_EPOCH_MAX_GAP", lambda v: v + 1),
    "same-epoch gap - 1": ("SAME_EPOCH_MAX_GAP", lambda v: v - 1),
    "backlog limit + 1 ms": ("BACKLOG_LIMIT", lambda v: v + 0.001),
    "backlog limit - 1 ms": ("BACKLOG_LIMIT", lambda v: v - 0.001),
    "max_ahead - 1": ("max_ahead", lambda f: lambda dt: f(dt) - 1),
    "max_ahead + 1": ("max_ahead", lambda f: lambda dt: f(dt) + 1),
}


@pytest.mark.skipif(not VECTORS, reason="HANDWHEEL_FEED_VECTORS not set (cargo xtask test sets it)")
@pytest.mark.parametrize("mutant", sorted(RULE_MUTANTS))
def test_the_boundary_vectors_notice_a_changed_limit(monkeypatch, mutant):
    boundaries = [v for v in load() if v["name"].startswith("boundary:")]
    assert _differs(boundaries) == [], "the rule as shipped agrees"
    name, change = RULE_MUTANTS[mutant]
    _patch(monkeypatch, name, change)
    assert _differs(boundaries), f"no boundary vector notices {mutant}"


@pytest.mark.skipif(not VECTORS, reason="HANDWHEEL_FEED_VECTORS not set (cargo xtask test sets it)")
@pytest.mark.parametrize("late", [-0.001, 0.001])
def test_the_boundary_vectors_notice_a_changed_stale_limit(monkeypatch, late):
    boundaries = [v for v in load() if v["name"].startswith("boundary:")]
    stale = core.Core.stale_after
    monkeypatch.setattr(core.Core, "stale_after", property(lambda c: stale.fget(c) + late))
    assert _differs(boundaries)
