"""The core answers, the decoder prints: `Core.frame` answers every feed record with a
`FeedVerdict`, and `canopen-handwheel decode` prints that answer and nothing of its own. Every
capture in `captures/` is decoded (with its host notes and without), each printed verdict is
compared with the one the core answered for that record, and the credits the verdicts add up
to with what the core and the pins end on."""

from pathlib import Path

import pytest

import records
from canopen_handwheel import capture, core, decode
from canopen_handwheel.core import BACKLOG_LIMIT, FeedVerdict, Reason
from canopen_handwheel.verdict import UncreditedMotion
from records import EN, SESSION, TPDO1

CAPTURES = sorted((Path(__file__).resolve().parent / "captures").glob("*.log.gz"))
# The decoder's verdict follows a frame's description after this.
ARROW = "  ->  "


@pytest.fixture
def answered(monkeypatch):
    """Every verdict a `Core` answers from now on (`Core.frame`), with the core that answered
    it, in order."""
    out = []
    frame = core.Core.frame

    def spy(self, cob_id, data, now):
        verdict = frame(self, cob_id, data, now)
        if verdict is not None:
            out.append((self, verdict))
        return verdict

    monkeypatch.setattr(core.Core, "frame", spy)
    return out


def feed_records(path: Path):
    """The device's feed records in the capture at `path` (every one the decoder judges)."""
    f = capture.read(path)
    cfg = capture.config_from_fields(f.config) if f.config else core.Config()
    return [
        fr
        for fr in f.frames
        if fr.id == 0x180 + cfg.node and not (fr.error or fr.extended or fr.remote)
    ]


def credited(verdicts, axes: str):
    """Per letter of `axes`: what `verdicts` credited, wrapping as the counts do."""
    sums = {letter: 0 for letter in axes}
    for v in verdicts:
        if v.credited:
            sums[v.axis] = core.wrap_s32(sums[v.axis] + v.delta)
    return sums


@pytest.mark.parametrize("notes", [[], ["--no-notes"]], ids=["notes", "no-notes"])
@pytest.mark.parametrize("path", CAPTURES, ids=lambda p: p.name.split(".")[0])
def test_the_decoder_prints_the_verdict_the_core_answered(path, notes, answered, capsys):
    assert decode.main(notes + [str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    printed = [line.split(ARROW, 1)[1] for line in out if ARROW in line]
    assert len(answered) == len(feed_records(path)) > 0
    assert printed == [v.text for _, v in answered]
    # The summary adds up the same answers, per core (a capture may hold several starts).
    cores = {id(c): c for c, _ in answered}.values()
    for c in cores:
        sums = credited([v for owner, v in answered if owner is c], c.cfg.axes)
        assert sums == c.counts == c.pins().jog_counts
    last = list(cores)[-1]
    for i, letter in enumerate(last.cfg.axes, start=1):
        name = core.OVERRIDES.get(letter, f"axis {letter.upper()}")
        sums = credited([v for owner, v in answered if owner is last], last.cfg.axes)
        assert any(line.startswith(f"  {i} {name}: credited {sums[letter]:+d} ") for line in out)


@pytest.mark.parametrize("path", CAPTURES, ids=lambda p: p.name.split(".")[0])
def test_a_replays_credits_are_what_its_pins_end_on(path):
    r = decode.replay([capture.read(path)])
    verdicts = [line.verdict for line in r.lines if line.verdict is not None]
    assert all(isinstance(v, FeedVerdict) for v in verdicts)
    assert len(verdicts) == len(feed_records(path))
    sums = credited(verdicts, r.cfg.axes)
    assert sums == r.core.counts == r.core.pins().jog_counts
    for letter, n in sums.items():
        name = core.OVERRIDES.get(letter)
        assert r.pins[f"{name}.counts" if name else f"axis.{letter}.jog-counts"] == n


def test_the_cores_answers():
    """One record of each common kind, at the core: what it credits, on which axis, why."""
    c = records.configured(core.Config(axes="xf"))  # `f`: the feed override (detents)
    c.set_enable(True)
    t = 0.0

    def send(position, seq, axis=1, epoch=1, mult=1, session=SESSION, dt=0.01, drained=True):
        nonlocal t
        t += dt
        if drained:
            c.drained(t)
        data = records.rec(position, axis, mult, EN, seq, epoch, session)
        return c.frame(TPDO1, data, t)

    assert c.frame(0x080 + records.NODE, bytes(8), t) is None  # not a feed record
    assert send(0, 1) == FeedVerdict(Reason.FIRST, axis="x")
    assert send(3, 2) == FeedVerdict(Reason.CREDITED, axis="x", delta=3, moved=3)
    assert send(3, 2) == FeedVerdict(Reason.DUPLICATE)
    v = send(0, 1)
    assert (v.reason, v.bad, v.kind, v.credited) == (Reason.COPY, True, decode.COPY, False)
    assert v.text == "a copy of an earlier record (1 numbers behind the newest); counted bad"
    v = send(5, 5)
    assert (v.reason, v.delta, v.lost) == (Reason.CREDITED, 2, 2)
    assert v.text == "credited X +2 (moved 2); 2 records lost before it"
    v = send(7, 6, drained=False, dt=BACKLOG_LIMIT * 1.5)
    assert (v.reason, v.moved, v.kind) == (Reason.LATE, 2, decode.BASELINE)
    assert send(7, 7, session=SESSION + 1).reason is Reason.OTHER_SESSION
    # The override selected at x10 (number 7 was the other session's: missing here), then
    # its detents.
    v = send(7, 8, axis=2, epoch=2, mult=10)
    assert (v.reason, v.axis, v.lost) == (Reason.OTHER_EPOCH, "f", 1)
    assert v.text == "baseline: epoch 1 -> 2 (1 on) across a gap of 1; 1 record lost before it"
    v = send(27, 9, axis=2, epoch=2, mult=10)
    assert (v.reason, v.axis, v.delta, v.moved) == (Reason.CREDITED, "f", 2, 20)
    assert v.text == "credited feed-override +2 (moved 20)"
    assert c.counts == {"x": 5, "f": 2}


def test_uncredited_motion_is_told_at_once_then_at_most_once_a_second():
    report = UncreditedMotion(interval=1.0)
    credited = FeedVerdict(Reason.CREDITED, axis="x", delta=3, moved=3)
    at_rest = FeedVerdict(Reason.AT_REST, axis="x")
    undated = FeedVerdict(Reason.UNDATED, axis="y", moved=-10, detail="last probe 0.412 s ago")
    assert not credited.motion_uncredited and not at_rest.motion_uncredited
    assert undated.motion_uncredited
    assert report.line(credited, 0.0) is None
    assert report.line(at_rest, 0.0) is None
    assert report.line(undated, 0.5) == (
        "motion not credited (Y, position -10): baseline: not dated within 0.35 s "
        "(last probe 0.412 s ago): held on its way?; position -10 since the last record "
        "taken, not credited"
    )
    assert report.line(undated, 0.9) is None
    assert report.line(undated, 1.4) is None
    line = report.line(FeedVerdict(Reason.NO_AXIS, moved=4, detail="axis 4"), 1.5)
    assert line == (
        "motion not credited (no axis, position +4): moved 4: axis 4 drives nothing (--axes) "
        "(and 2 more since the last such line)"
    )
    assert report.line(undated, 2.49) is None
    assert report.line(undated, 2.5) is not None
