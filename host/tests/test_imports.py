"""The decoder and the update command load without the HAL component: neither imports
`component` (nor the decoder's pin replay, which does), so they run where the component's
shell does not."""

import json
import os
import subprocess
import sys
from pathlib import Path

import canopen_handwheel

SRC = Path(canopen_handwheel.__file__).resolve().parents[1]
CHECK = """
import json, sys
import canopen_handwheel.decode, canopen_handwheel.update_cli
print(json.dumps(sorted(m for m in sys.modules if m.startswith("canopen_handwheel"))))
"""


def test_the_decoder_and_the_update_command_import_no_hal_code():
    env = dict(os.environ, PYTHONPATH=str(SRC))
    out = subprocess.run(
        [sys.executable, "-c", CHECK], env=env, capture_output=True, text=True, check=True
    ).stdout
    loaded = json.loads(out)
    assert "canopen_handwheel.decode" in loaded and "canopen_handwheel.update_cli" in loaded
    assert "canopen_handwheel.component" not in loaded, loaded
    assert "canopen_handwheel.pin_replay" not in loaded, loaded
