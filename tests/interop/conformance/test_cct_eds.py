"""CCT case 1.0 EDS checker (the tool runs Vector's CANchkEDS): structural checks of
eds/handwheel.eds after CiA 306, without the emulator.

CANchkEDS warns (warning 4, and 5 for a PDO mapping naming it) about a mappable entry whose
access type gives no direction (rw): its verdict is then "Warning", as in the tool's run
against CANopenNode, whose rw outputs 0x6200 drew it. The handwheel's one such entry is its
outputs 0x6A00:1 (rw, as CiA 401 gives 0x6200), RPDO1's default mapping; every other mappable
entry is ro."""

import configparser
import re

from rig import EDS

BITS = {0x2: 8, 0x3: 16, 0x4: 32, 0x5: 8, 0x6: 16, 0x7: 32}


def test_eds_checker():
    eds = configparser.ConfigParser(interpolation=None, strict=True)
    eds.optionxform = str
    eds.read(EDS)
    listed = []
    for section in ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"):
        s = eds[section]
        n = int(s["SupportedObjects"], 0)
        entries = [int(s[str(i)], 0) for i in range(1, n + 1)]
        assert len(s) == n + 1, f"[{section}] has entries beyond SupportedObjects"
        listed += entries
    assert {0x1000, 0x1001, 0x1018} <= set(listed)
    undirected = []
    objects = {int(name, 16) for name in eds.sections() if re.fullmatch(r"[0-9A-F]{4}", name)}
    assert sorted(listed) == sorted(objects), "object lists and object sections differ"
    for index in objects:
        s = eds[f"{index:04X}"]
        assert "ParameterName" in s and "ObjectType" in s
        if int(s["ObjectType"], 0) in (0x8, 0x9):
            subs = [n for n in eds.sections() if re.fullmatch(f"{index:04X}sub[0-9A-F]+", n)]
            assert len(subs) == int(s["SubNumber"], 0), f"{index:04X} SubNumber"
            variables = [eds[n] for n in subs]
        else:
            variables = [s]
        for v in variables:
            assert v["AccessType"] in ("ro", "wo", "rw", "rwr", "rww", "const")
            if v.get("PDOMapping", "0") == "1" and v["AccessType"] not in ("ro", "rwr"):
                undirected.append(v.name)
    # The entries CANchkEDS warns about (no clear mapping direction): the outputs only.
    assert undirected == ["6A00sub1"]
    info = eds["DeviceInfo"]
    rpdos = [i for i in objects if 0x1400 <= i <= 0x15FF]
    tpdos = [i for i in objects if 0x1800 <= i <= 0x19FF]
    assert (int(info["NrOfRXPDO"]), int(info["NrOfTXPDO"])) == (len(rpdos), len(tpdos)) == (1, 2)
    # Each PDO has its mapping; the default entries name objects of their direction and size.
    for comm, mapping, direction in [(i, i + 0x200, ("rw", "wo", "rww")) for i in rpdos] + [
        (i, i + 0x200, ("ro", "rw", "rwr")) for i in tpdos
    ]:
        assert mapping in objects, f"{comm:04X} without {mapping:04X}"
        count = int(eds[f"{mapping:04X}sub0"]["DefaultValue"], 0)
        for sub in range(1, count + 1):
            entry = int(eds[f"{mapping:04X}sub{sub:X}"]["DefaultValue"], 0)
            name = f"{entry >> 16:04X}sub{(entry >> 8) & 0xFF:X}"
            target = eds[name if eds.has_section(name) else name.split("sub")[0]]
            assert target.get("PDOMapping") == "1" and target["AccessType"] in direction
            assert BITS[int(target["DataType"], 0)] == entry & 0xFF, f"{mapping:04X}:{sub}"
    # Dummy mapping (CiA 306 [DummyUsage]): RPDO1 takes INTEGER8..UNSIGNED32 (0x0002..0x0007).
    dummies = eds["DummyUsage"]
    assert {k: dummies[k] for k in dummies} == {
        f"Dummy{i:04X}": "1" if 2 <= i <= 7 else "0" for i in range(1, 8)
    }
