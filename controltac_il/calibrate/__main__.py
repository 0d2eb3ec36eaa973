"""``python -m controltac_il.calibrate``: see the package docstring."""

from controltac_il.calibrate.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
