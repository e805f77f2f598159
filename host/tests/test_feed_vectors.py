"""The component's rule against the model checker's: every record stream in the vectors that
`crates/feed-check` writes (`feed-check --vectors FILE`, run by `cargo xtask test`, which sets
HANDWHEEL_FEED_VECTORS) is replayed through `core.replay`, and the per-axis counts must be
exactly what the checker's rule credited for it. The checker proves its rule safe against the
real device code; this keeps `core.py` the same rule. Since feed record v2 a stream holds the
configurations its host made (("configure", found, t): `core.replay_core`), so that its
records carry the session the core wrote; the tokens must be the ones `core.free_tokens` and
`core.pick_token` choose. Besides the model's random walks, the vectors hold streams at each
limit of the rule, met and missed by one (`crates/feed-check/src/boundaries.rs`)."""

import json
import os
from pathlib import Path

import pytest

from canopen_handwheel import core

VECTORS = os.environ.get("HANDWHEEL_FEED_VECTORS")


def load():
    lines = Path(VECTORS).read_text().splitlines() if VECTORS else []
    return [json.loads(line) for line in lines if line.strip()]


@pytest.mark.skipif(not VECTORS, reason="HANDWHEEL_FEED_VECTORS not set (cargo xtask test sets it)")
def test_core_credits_exactly_what_the_checked_rule_credits():
    vectors = load()
    assert len(vectors) >= 1000, "the checker wrote its vectors"
    moved = 0
    for n, v in enumerate(vectors):
        events = [tuple(e) for e in v["events"]]
        counts = core.replay(events, core.Config(axes="xy"))
        want = v["counts"]
        assert (counts["x"], counts["y"]) == (want["x"], want["y"]), (n, v["name"])
        moved += bool(want["x"] or want["y"])
    # The vectors must exercise crediting, not only silence.
    assert moved >= len(vectors) // 4
    # And every limit of the rule met exactly and missed by one (`boundaries.rs`).
    boundaries = [v["name"] for v in vectors if v["name"].startswith("boundary:")]
    assert len(boundaries) >= 21, boundaries
