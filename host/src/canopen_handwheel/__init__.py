"""A LinuxCNC userspace HAL component for the CANopen CNC handwheel (python-canopen master).

`core` holds the decisions (no HAL, no CAN); `component` is the thin HAL and CAN shell with
the `canopen-handwheel` console script.
"""

__version__ = "0.1.0"
