"""CCT case 1.0 EDS checker (the tool runs Vector's CANchkEDS): structural checks of
eds/handwheel.eds after CiA 306, without the emulator."""

import configparser
import re

from rig import EDS


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
            if v.get("PDOMapping", "0") == "1":
                # Only transmit PDOs: a mappable entry must have a clear direction (ro).
                assert v["AccessType"] in ("ro", "rwr"), f"{index:04X} mapping direction"
    info = eds["DeviceInfo"]
    assert int(info["NrOfRXPDO"]) == sum(1 for i in objects if 0x1400 <= i <= 0x15FF)
    assert int(info["NrOfTXPDO"]) == sum(1 for i in objects if 0x1800 <= i <= 0x19FF)
