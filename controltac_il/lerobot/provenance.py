"""The provenance features the augment command writes into a LeRobot folder, per frame: ``augment.copy`` (0 = the
recorded frame), ``augment.offset`` and ``augment.jitter`` (N), and per tactile camera ``augment.<camera>.status``
and ``augment.<camera>.target_force`` (3,) N, named by the camera key's last part."""

from __future__ import annotations

from controltac_il.streams import lerobot_name

PREFIX = "augment"
COPY = f"{PREFIX}.copy"  # the copy a frame belongs to, 0 = recorded


def provenance_names(tactile_keys) -> dict[str, str]:
    """tactile key -> the camera name of its provenance features; ValueError naming ``tactile_keys``."""
    names = {k: lerobot_name(k) for k in tactile_keys}
    bad = [n for n in names.values() if "image" in n or list(names.values()).count(n) > 1]
    if bad:
        raise ValueError(f"tactile_keys: provenance features are named by each camera's last name part, which must "
                         f"be unique and free of 'image'; got {list(names.values())}")
    return names


def provenance_features(names: dict[str, str]) -> dict:
    """info.json features of the provenance columns."""
    scalar = {"shape": [1], "names": None}
    out = {COPY: {"dtype": "int64", **scalar}, f"{PREFIX}.offset": {"dtype": "float32", **scalar},
           f"{PREFIX}.jitter": {"dtype": "float32", **scalar}}
    for n in names.values():
        out[f"{PREFIX}.{n}.status"] = {"dtype": "int64", **scalar}
        out[f"{PREFIX}.{n}.target_force"] = {"dtype": "float32", "shape": [3], "names": ["fx", "fy", "fz"]}
    return out
