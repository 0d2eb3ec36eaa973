"""The shipped checkpoints by name, and the folder a name, a checkpoint folder or a calibration bundle points to.
Torch-free, so that the CLIs' ``--help`` can name them."""

from __future__ import annotations

from pathlib import Path

CHECKPOINT_ROOT = Path(__file__).resolve().parent / "checkpoints"
SHIPPED = ("default", "fast", "quality")  # the presets: speed against error, docs/generator.md
# shipped so that the speed-error frontier reproduces (benchmarks.generator): sizes trained under the quality
# preset's protocol, loadable by name, not presets
FRONTIER_SIZES = ("frontier_tiny", "frontier_small")
SHIPPED_ADAPTERS = ("pose",)  # stage-2 pose adapters, each trained on the shipped default

BUNDLE_PART = "generator"  # a calibration bundle's generator subfolder (python -m controltac_il.calibrate)


def locate_checkpoint(path: str | Path | None = None, shipped: tuple[str, ...] = (*SHIPPED, *FRONTIER_SIZES)) -> Path:
    """The checkpoint folder ``from_pretrained(path)`` loads: ``None``/``"default"``, ``"fast"`` and ``"quality"``
    name the shipped presets, ``FRONTIER_SIZES`` the frontier's other shipped sizes (``shipped``: the names to
    accept, ``SHIPPED_ADAPTERS`` for stage 2); a calibration bundle gives its ``generator/``."""
    if path is None:
        path = shipped[0]
    if isinstance(path, str) and path in shipped:
        path = CHECKPOINT_ROOT / path
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"{'pose adapter' if shipped == SHIPPED_ADAPTERS else 'generator'} checkpoint folder "
                                f"{path} not found")
    if shipped != SHIPPED_ADAPTERS and (path / BUNDLE_PART).is_dir() and not (path / "config.json").is_file():
        return path / BUNDLE_PART  # a calibration bundle (python -m controltac_il.calibrate)
    return path
