"""``python -m controltac_il.generator.training``: the generator's training command line (``cli``)."""

from controltac_il.generator.training.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
