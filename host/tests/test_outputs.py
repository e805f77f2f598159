"""The outputs the CNC drives (RPDO1, host/README.md "Outputs"): the byte from the pins, when
the device may get it, and when frames go out (`OutputSchedule`), checked on every input
sequence hypothesis draws, with the component's outputs thread stood in for by a loop that
asks the schedule whenever an input changes and whenever it said it would send next."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canopen_handwheel import core
from canopen_handwheel.outputs import (
    DEFAULT_OUTPUT_PERIOD_MS,
    OUTPUT_INHIBIT,
    OutputSchedule,
    describe_outputs,
    output_byte,
    output_period,
    outputs_allowed,
)
from canopen_handwheel.record import BOOTUP, OPERATIONAL, PRE_OPERATIONAL, STOPPED

PERIOD = DEFAULT_OUTPUT_PERIOD_MS / 1000
# Float sums of times: a frame "at" a bound may land this far past it.
EPS = 1e-9


def test_the_byte_has_machine_on_in_bit_0_and_out_n_in_bit_n():
    assert output_byte(False, [False] * 6) == 0
    assert output_byte(True, [False] * 6) == 0x01
    for n in range(1, 7):
        outs = [k == n for k in range(1, 7)]
        assert output_byte(False, outs) == 1 << n
    assert output_byte(True, [True] * 6) == 0x7F  # bit 7 has no pin
    with pytest.raises(ValueError):
        output_byte(True, [True] * 7)


def test_describe_outputs_names_the_pins():
    assert describe_outputs(0) == "outputs: all off"
    assert describe_outputs(0x05) == "outputs: machine on, out-2"
    assert describe_outputs(0x80) == "outputs: bit 7"


def test_the_period_option_is_checked():
    assert output_period(100) == 0.1
    for wrong in (0, 19, 1001):
        with pytest.raises(ValueError):
            output_period(wrong)
    assert core.make_config(16, None, "xyz", 0.001, None, 100).output_period == PERIOD
    assert core.make_config(16, None, "xyz", 0.001, None, 100, output_period_ms=50).output_period
    with pytest.raises(ValueError):
        core.make_config(16, None, "xyz", 0.001, None, 100, output_period_ms=5)


@pytest.mark.parametrize(
    "session, fresh, state, foreign, allowed",
    [
        (1, True, OPERATIONAL, False, True),
        (1, True, None, False, True),  # a device without heartbeat: its records tell
        (None, True, OPERATIONAL, False, False),  # not configured by this component
        (1, False, OPERATIONAL, False, False),  # lost: no record for three periods
        (1, True, STOPPED, False, False),
        (1, True, PRE_OPERATIONAL, False, False),
        (1, True, BOOTUP, False, False),
        (1, True, OPERATIONAL, True, False),  # the newest record is another session's
    ],
)
def test_outputs_go_only_to_a_configured_operational_device(
    session, fresh, state, foreign, allowed
):
    assert outputs_allowed(session, fresh, state, foreign) is allowed


def test_the_core_allows_outputs_from_its_sessions_first_record_until_it_is_lost():
    """Through the core's own events: none before the configuration, none between it and
    the first record of the session (the device is not started yet), then while records
    come; a Stopped heartbeat, staleness and a boot-up end it."""
    c = core.Core(core.Config(axes="xyz"))
    assert not c.outputs_live
    action = c.next_action(0.0)
    assert isinstance(action, core.Configure)
    ok, result = core.configure_outcome(action, 0, c.event_timer)
    c.done(action, ok, None, 0.0, result)
    session = c.session
    assert session is not None and not c.outputs_live
    record = core.Record(0, 1, 1, 1, 0, session, 1)
    c.frame(0x190, record.encode(), 0.01)
    assert c.outputs_live
    c.frame(0x710, bytes([STOPPED]), 0.02)
    assert not c.outputs_live
    c.frame(0x710, bytes([OPERATIONAL]), 0.03)
    assert c.outputs_live
    c.tick(0.01 + 3 * c.event_timer + 0.001)
    assert not c.outputs_live  # lost
    c.frame(0x190, core.Record(0, 1, 1, 1, 0, session, 2).encode(), 0.5)
    assert c.outputs_live
    c.frame(0x710, bytes([BOOTUP]), 0.51)
    assert not c.outputs_live and c.session is None


# The schedule ----------------------------------------------------------------------------


def simulate(inputs, period=PERIOD, inhibit=OUTPUT_INHIBIT, tail=None):
    """Runs `OutputSchedule` over `inputs`, a list of (time, byte, allowed) in time order
    (the inputs before the first: 0, not allowed), asking it at every input and whenever it
    said it would send next, until `tail` after the last input (3 periods by default).
    Returns the frames [(t, byte)] and a function giving the inputs at a time."""
    schedule = OutputSchedule(period=period, inhibit=inhibit)
    frames = []
    byte, allowed, now = 0, False, 0.0
    end = (inputs[-1][0] if inputs else 0.0) + (3 * period if tail is None else tail)

    def run_until(t):
        nonlocal now
        while True:
            wake = max(now, schedule.wake_at(now, byte, allowed))
            if wake >= t or math.isinf(wake):
                return
            now = wake
            sent = schedule.due(now, byte, allowed)
            assert sent is not None, "wake_at promised a frame"
            frames.append((now, sent))

    for t, b, a in inputs:
        run_until(t)
        now, byte, allowed = t, b, a
        sent = schedule.due(now, byte, allowed)
        if sent is not None:
            frames.append((now, sent))
    run_until(end)

    def at(t):
        state = (0, False)
        for ti, b, a in inputs:
            if ti <= t:
                state = (b, a)
        return state

    return frames, at, end


@st.composite
def input_sequences(draw):
    """Inputs changing at random times: bursts closer than the inhibit time, pauses longer
    than the period, the device allowed and not."""
    steps = draw(
        st.lists(
            st.tuples(
                st.one_of(
                    st.floats(0.0001, 0.004),  # within one inhibit time
                    st.floats(0.004, 0.03),
                    st.floats(0.03, 0.35),  # across periods
                ),
                st.integers(0, 0x7F),
                st.booleans() | st.just(True),
            ),
            min_size=1,
            max_size=40,
        )
    )
    t, out = 0.0, []
    for dt, byte, allowed in steps:
        t += dt
        out.append((t, byte, allowed))
    return out


@settings(max_examples=400, deadline=None)
@given(input_sequences())
def test_frames_are_never_closer_than_the_inhibit_time(inputs):
    frames, _, _ = simulate(inputs)
    for (a, _), (b, _) in zip(frames, frames[1:]):
        assert b - a >= OUTPUT_INHIBIT - EPS


@settings(max_examples=400, deadline=None)
@given(input_sequences())
def test_nothing_goes_out_while_not_allowed_and_every_frame_has_the_byte_of_its_time(inputs):
    frames, at, _ = simulate(inputs)
    for t, sent in frames:
        byte, allowed = at(t)
        assert allowed and sent == byte, (t, sent, byte)


def stretch_start(inputs, i):
    """When the device became allowed for the stretch that input `i` is in."""
    start = inputs[i][0]
    while i >= 0 and inputs[i][2]:
        start = inputs[i][0]
        i -= 1
    return start


def on_the_bus(frames, stretch, deadline):
    """The byte the device holds from this component at `deadline`: the last frame sent by
    then within the stretch, or None."""
    sent = [b for t, b in frames if stretch <= t <= deadline + EPS]
    return sent[-1] if sent else None


@settings(max_examples=400, deadline=None)
@given(input_sequences())
def test_every_change_reaches_the_bus_within_the_inhibit_time(inputs):
    """A change of the byte, or the device becoming allowed, at `t`: within the inhibit
    time the last frame of the stretch carries it, unless the inputs change again before
    then (the later change is then the one owed)."""
    frames, _, _ = simulate(inputs)
    for i, (t, byte, allowed) in enumerate(inputs):
        next_change = inputs[i + 1][0] if i + 1 < len(inputs) else math.inf
        deadline = t + OUTPUT_INHIBIT
        if not allowed or next_change <= deadline:
            continue
        assert on_the_bus(frames, stretch_start(inputs, i), deadline) == byte, (t, byte)


@settings(max_examples=400, deadline=None)
@given(input_sequences())
def test_the_last_value_always_goes_out(inputs):
    frames, _, _ = simulate(inputs)
    t_last, byte, allowed = inputs[-1]
    if allowed:
        stretch = stretch_start(inputs, len(inputs) - 1)
        assert on_the_bus(frames, stretch, t_last + OUTPUT_INHIBIT) == byte
        assert frames[-1][1] == byte and frames[-1][0] > t_last + OUTPUT_INHIBIT
    else:
        assert not [t for t, _ in frames if t >= t_last]


@settings(max_examples=400, deadline=None)
@given(input_sequences(), st.sampled_from([0.02, 0.05, 0.1, 1.0]))
def test_the_period_holds_while_allowed(inputs, period):
    """While allowed, consecutive frames are at most a period apart, and exactly a period
    while nothing changes; a stretch of being allowed begins with a frame at once (or at
    the end of the inhibit time)."""
    frames, at, end = simulate(inputs, period=period)
    times = [t for t, _ in frames]
    for a, b in zip(times, times[1:]):
        if all(at(t)[1] for t in (a, b)) and all(at(ti)[1] for ti, _, _ in inputs if a < ti <= b):
            assert b - a <= period + EPS, (a, b)
    # The tail after the last input: exactly the period between frames.
    t_last, _, allowed = inputs[-1]
    tail = [t for t in times if t > t_last + OUTPUT_INHIBIT]
    if allowed:
        assert len(tail) >= 2
        for a, b in zip(tail, tail[1:]):
            assert b - a == pytest.approx(period)
        assert end - tail[-1] <= period + EPS


def test_a_change_within_the_inhibit_time_goes_out_at_its_end():
    s = OutputSchedule(period=0.1, inhibit=0.01)
    assert s.due(1.0, 0x01, True) == 0x01
    assert s.due(1.004, 0x03, True) is None
    assert s.wake_at(1.004, 0x03, True) == pytest.approx(1.01)
    assert s.due(1.0099, 0x03, True) is None
    assert s.due(1.01, 0x03, True) == 0x03
    assert s.wake_at(1.01, 0x03, True) == pytest.approx(1.11)
    assert s.due(1.05, 0x03, True) is None
    assert s.due(1.11, 0x03, True) == 0x03


def test_a_stretch_not_allowed_ends_the_repeats_and_the_next_begins_with_a_frame():
    s = OutputSchedule(period=0.1, inhibit=0.01)
    assert s.due(0.0, 0x01, True) == 0x01
    assert s.due(0.005, 0x01, False) is None
    assert s.wake_at(0.005, 0x01, False) == math.inf
    assert s.due(0.5, 0x01, False) is None
    assert s.due(0.5, 0x01, True) == 0x01  # the same byte, sent again at once
    assert s.due(0.505, 0x01, False) is None
    assert s.due(0.507, 0x01, True) is None  # the inhibit holds across the gap
    assert s.due(0.51, 0x01, True) == 0x01


def test_a_failed_send_goes_again_after_the_inhibit_time():
    s = OutputSchedule(period=0.1, inhibit=0.01)
    assert s.due(0.0, 0x02, True) == 0x02
    s.unsent()
    assert s.wake_at(0.001, 0x02, True) == pytest.approx(0.01)
    assert s.due(0.01, 0x02, True) == 0x02


# The component: its outputs thread on a virtual bus ---------------------------------------


def test_the_component_sends_the_outputs_only_to_its_started_device_and_at_once():
    """On a virtual bus with the stand-in device: no RPDO1 before the configuration and the
    device's first record of the session; then the pins' byte at once, again every period;
    a change of `machine-on` within a few milliseconds (the loop's round and the inhibit
    time); `outputs-live` and `outputs-sent` follow; a Stopped heartbeat ends the frames,
    and so does the component's end."""
    import time

    from test_component import NODE, Device, Running, wait

    rpdo1 = core.RPDO1 + NODE
    channel = f"out-{time.monotonic_ns()}"
    dev = Device(channel)
    running = Running(channel, "--output-period-ms", "50")
    comp = running.comp
    try:
        comp["out-3"] = True
        wait(lambda: dev.seen(0x000, bytes([1, NODE])), what="NMT start")
        time.sleep(0.2)
        assert not dev.seen(rpdo1), "outputs before the device's first record"
        assert not comp["outputs-live"]
        wait(lambda: dev.record(0, epoch=1) or comp["connected"], what="connected")
        wait(lambda: dev.seen(rpdo1), what="the first outputs frame")
        assert dev.seen(rpdo1)[0] == bytes([0x08])  # out-3: bit 3
        wait(lambda: comp["outputs-live"], what="outputs-live")
        # Kept fresh by records; the byte repeats every 50 ms.
        mark = dev.mark()
        for _ in range(10):
            dev.record(0, epoch=1)
            time.sleep(0.03)
        with dev.lock:
            times = [t for (i, _), t in zip(dev.frames[mark:], dev.times[mark:]) if i == rpdo1]
        gaps = [b - a for a, b in zip(times, times[1:])]
        assert gaps and all(0.04 < g < 0.07 for g in gaps), gaps
        # machine-on: at once.
        changed = time.time()  # the virtual bus stamps frames with it
        comp["machine-on"] = True
        wait(lambda: dev.seen(rpdo1, bytes([0x09])), timeout=1.0, what="machine on sent")
        took = dev.seen_at(rpdo1)[dev.seen(rpdo1).index(bytes([0x09]))] - changed
        print("machine-on to RPDO1:", took)
        assert took < 0.05, took
        dev.record(0, epoch=1)
        wait(lambda: comp["outputs-sent"] == len(dev.seen(rpdo1)), what="outputs-sent")
        # A Stopped heartbeat: no frame after the component has seen it.
        dev.network.send_message(0x700 + NODE, bytes([STOPPED]))
        wait(lambda: not comp["outputs-live"], what="outputs-live off")
        count = len(dev.seen(rpdo1))
        comp["machine-on"] = False
        time.sleep(0.2)
        assert len(dev.seen(rpdo1)) == count
    finally:
        running.end()
        dev.close()
