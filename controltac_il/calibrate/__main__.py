"""``python -m controltac_il.calibrate``: see the package docstring. ``... calibrate record`` records the presses
with a robot (``controltac_il.app.record_cli``, the wiring: it drives the robot through ``hardware``)."""

import sys

if __name__ == "__main__":
    if sys.argv[1:2] == ["record"]:
        from controltac_il.app.record_cli import main as record

        raise SystemExit(record(sys.argv[2:]))
    from controltac_il.calibrate.cli import main

    raise SystemExit(main())
