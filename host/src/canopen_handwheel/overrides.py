"""Switch positions that drive LinuxCNC's overrides instead of an axis (`OVERRIDES`), and
the `--axes` option that places them (`parse_axes`)."""

from __future__ import annotations

# One detent at an override position changes the override by this many percent
# (`--override-step`), whatever the multiplier.
DEFAULT_OVERRIDE_STEP = 1.0
OVERRIDE_STEP_RANGE = (0.01, 100.0)


# Switch positions that drive one of LinuxCNC's overrides instead of an axis (`--axes`): the
# letter and the name its pins carry (`N.feed-override.counts`, ...).
OVERRIDES = {"f": "feed-override", "s": "spindle-override", "r": "rapid-override"}
LINUXCNC_AXES = "xyzabcuvw"


def parse_axes(letters: str) -> str:
    """The `--axes` option checked: in switch order, at least one and at most five of the
    LinuxCNC axis letters `xyzabcuvw` and the override letters `f` (feed), `s` (spindle),
    `r` (rapid), each at most once.

    Position n of the switch (1..5) drives the n-th letter, so `xyzfs` puts X, Y, Z on
    positions 1..3 and the feed and spindle overrides on 4 and 5.
    """
    letters = letters.strip().lower()
    if not 1 <= len(letters) <= 5:
        raise ValueError("--axes needs 1 to 5 letters (axes, or f, s, r for the overrides)")
    twice = sorted({c for c in letters if letters.count(c) > 1})
    if twice:
        raise ValueError(f"--axes {letters!r} names {''.join(twice)!r} twice")
    bad = [c for c in letters if c not in LINUXCNC_AXES and c not in OVERRIDES]
    if bad:
        raise ValueError(
            f"--axes {letters!r}: {''.join(bad)!r} is neither a LinuxCNC axis letter "
            "(xyzabcuvw) nor an override (f feed, s spindle, r rapid)"
        )
    return letters
