"""``python -m controltac_il.sign FOLDER [FOLDER ...]``: record the SHA-256 of each checkpoint folder's weights in
its model card (for folders written before the card carried them: check their contents first)."""

from __future__ import annotations

from pathlib import Path

from controltac_il.checkpoint import HASH_KEY, sign
from controltac_il.cli import ArgumentParser, guard

PROG = "python -m controltac_il.sign"


def main(argv=None) -> int:
    """0 signed; 2 (one line) for a folder that does not exist, holds no .safetensors file, or an unreadable card."""
    p = ArgumentParser(prog=PROG, description="Record the SHA-256 of each checkpoint folder's weights in its "
                       "model card (check the folder's contents first: the card then vouches for them).")
    p.add_argument("folders", nargs="+", type=Path, help="checkpoint folders (config.json, *.safetensors)")
    folders = p.parse_args(argv).folders
    for folder in folders:
        if not folder.is_dir() or not any(folder.glob("*.safetensors")):
            raise ValueError(f"{folder}: not a checkpoint folder (no .safetensors file in it); nothing was signed")
    for folder in folders:
        print(folder, sign(folder)[HASH_KEY])
    return 0


if __name__ == "__main__":
    raise SystemExit(guard(PROG, main))
