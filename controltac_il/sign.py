"""``python -m controltac_il.sign FOLDER [FOLDER ...]``: record the SHA-256 of each checkpoint folder's weights in
its model card (for folders written before the card carried them: check their contents first)."""

from __future__ import annotations

import argparse
from pathlib import Path

from controltac_il.checkpoint import HASH_KEY, sign


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m controltac_il.sign",
                                description="Record the SHA-256 of a checkpoint folder's weights in its model card.")
    p.add_argument("folders", nargs="+", type=Path)
    for folder in p.parse_args(argv).folders:
        print(folder, sign(folder)[HASH_KEY])


if __name__ == "__main__":
    main()
