"""SDO channels: another master's exchanges with the device (`FOREIGN_SDO_QUIET`), the
component's own channel (`own_sdo_ids`, `parse_sdo_channel`), the loader's answers."""

from __future__ import annotations

from typing import Optional, Tuple

from .update_contract import LOADER_DEVICE_TYPE as LOADER_DEVICE_TYPE

# SDO abort: "data cannot be transferred because of the present device state".
ABORT_DEVICE_STATE = 0x08000022

# The resident loader's device type 0x1000 (`LOADER_DEVICE_TYPE`, "BOOT", from the update
# contract, docs/FIRMWARE-UPDATE.md): a device that answers with it runs no application and
# sends no feed records.

# Another master's SDO exchange with the device (`canopen-handwheel update`, a configuration
# tool): CiA 301's default SDO channel (0x600 + node, 0x580 + node) serves one client at a
# time, and either client takes the other's answer for its own, so the component sends no
# SDO request until that master has sent none for this long. Longer than the gaps inside a
# program download (0x1F57 polled every 0.05 s; the boot-up after "start" comes within
# milliseconds on the board), short against a person's pause.
FOREIGN_SDO_QUIET = 2.0
# Except after another master's expedited read (an HMI polling, say 0x1001 once a second),
# which is over with its answer: the hold then ends FOREIGN_READ_QUIET after the answer, or
# the component, whose probes date every record, would credit nothing while the HMI polls.
# The short quiet keeps a master that reads and goes on at once (an update's first steps)
# undisturbed; a read of the program download objects (0x1F50..0x1F5F: an update under way)
# keeps the long one. At most PROBE_PERIOD + FOREIGN_READ_QUIET between two probes stays
# within DATE_LIMIT. Either client's python-canopen refuses an answer for another object
# than it asked for, so a collision costs a retry.
FOREIGN_READ_QUIET = 0.15
PROGRAM_OBJECTS = range(0x1F50, 0x1F60)
# The component's own SDO channel: the device's second SDO server (0x1201), set up by every
# configuration, so that its probes (ten a second) and feed writes never share the default
# channel with another master, whose python-canopen would take an answer to a write of the
# component's for its own (it checks no index in a download's answer). COB-IDs from a range
# the pre-defined connection set leaves free (0x680..0x6DF): the master node-ID m (1..127)
# picks 0x680 + (m - 1) mod 48 to the device and 0x6B0 + the same from it; `--sdo-channel`
# sets others or none (then everything goes on the default channel, held back as above).
OWN_SDO_RANGE = range(0x680, 0x6E0)
OWN_SDO_PAIRS = 48
SDO_SERVER_2 = 0x1201
# The device does not store 0x1201: a power cycle or a reset of communication the host did not
# see, or another master's write of it, leaves the component's own channel unanswered, so that
# every probe on it times out. Nothing is then credited (no probe dates a record), but
# unanswered probes alone would keep the session (and the wheel dead) for good when the
# device's records still carry the component's token. So after this many probes in a row on
# the own channel without any answer (no reply at all; an abort is an answer) the host drops
# its session and configures the device again on the default channel, which sets 0x1201 up
# again. Three: one or two can be lost to a busy bus without costing the session, and at
# PROBE_PERIOD plus python-canopen's SDO timeout (0.3 s) each, the wheel is dead about 1 s at
# most before the configuration starts. (Not a check that keeps an intact session: the
# configuration writes 0x1201 by construction, whatever else made the channel silent.)
PROBE_TIMEOUTS_BEFORE_CONFIGURING = 3
# Sessions in a row dropped that way, no probe on the own channel answered in between, before
# the core configures without it (the default channel): the first drop sets the channel up
# again (a power cycle or another master's write silenced it); a second says the bus or a
# gateway does not carry the channel's identifiers, and configuring it again would only burn
# a session token a second (each kept out for `COPY_AGE` after).
OWN_CHANNEL_DROPS_BEFORE_DEFAULT = 2


def own_sdo_ids(master: int) -> Tuple[int, int]:
    """(to the device, from it): the component's own SDO channel for master node-ID `master`."""
    m = (master - 1) % OWN_SDO_PAIRS
    return OWN_SDO_RANGE.start + m, OWN_SDO_RANGE.start + OWN_SDO_PAIRS + m


def parse_sdo_channel(text: str, master: int) -> Optional[Tuple[int, int]]:
    """`--sdo-channel`: "auto" (`own_sdo_ids`), "none", or two COB-IDs "RX,TX" (hex or
    decimal, distinct, in 0x680..0x6DF); `ValueError` otherwise."""
    if text == "auto":
        return own_sdo_ids(master)
    if text == "none":
        return None
    try:
        rx, tx = (int(part, 0) for part in text.split(","))
    except ValueError:
        raise ValueError(f"--sdo-channel {text!r}: auto, none or RX,TX") from None
    if rx == tx or rx not in OWN_SDO_RANGE or tx not in OWN_SDO_RANGE:
        raise ValueError(f"--sdo-channel {text!r}: two distinct COB-IDs in 0x680..0x6DF")
    return rx, tx


# Program control 0x1F51:1 (CiA 302-3): "stop" resets the application into its loader.
PROGRAM_CONTROL = b"\x51\x1f\x01"
PROGRAM_STOP = 0
