"""The `canopen-handwheel` command: the HAL component (`component.main`), or with `decode`
as its first argument the capture decoder (`decode.main`), with `update` the firmware update
over CAN (`update_cli.main`)."""

from __future__ import annotations

import sys
from typing import Optional, Sequence


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] == ["decode"]:
        from . import decode

        return decode.main(args[1:])
    if args[:1] == ["update"]:
        from . import update_cli

        return update_cli.main(args[1:])
    from . import component

    return component.main(args)


if __name__ == "__main__":
    sys.exit(main())
