"""``python -m controltac_il.calibrate`` (and ``controltac-calibrate``): see the package docstring. ``... calibrate
record`` records the presses with a robot (``controltac_il.app.record_cli``, the wiring: it drives the robot
through ``hardware``)."""

import sys


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["record"]:
        from controltac_il.app.record_cli import main as record

        return record(argv[1:])
    from controltac_il.calibrate.cli import main as calibrate

    return calibrate(argv)


if __name__ == "__main__":
    raise SystemExit(main())
