"""What an episode file must satisfy before anything trains on it; every error names the file and the key.

Checked per file (``check_episode``): the file opens as HDF5; ``/action`` and ``/observations/qpos``
exist; every stream has its layout's axes (``SHAPES``); every per-frame stream (action, qpos, qvel, images,
tactile, force) has the same number of frames; images are uint8 and a tactile background has its frames' shape;
qpos and actions are finite; force labels are finite, in N (|F| <= MAX_PLAUSIBLE_FORCE_N) and pressing with
Fz > 0. Checked across files (``check_same_streams``, ``check_same_layout``): every episode records the same
cameras, tactile sensors and force labels, with the same shapes.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from controltac_il.tactile.spec import MAX_PLAUSIBLE_FORCE_N

CONTACT_N = 0.05  # |F| above which a label counts as contact when checking the sign of Fz
PER_FRAME_GROUPS = ("images", "tactile", "force")
SHAPES = {"vector": (2, None, "(T, D)"), "images": (4, 3, "(T, H, W, 3)"), "tactile": (4, 3, "(T, H, W, 3)"),
          "force": (2, 3, "(T, 3) [Fx, Fy, Fz] N"), "tactile_background": (3, 3, "(H, W, 3)")}  # (axes, last, text)
OBSERVATIONS = "observations"  # the group of every per-frame observation (ALOHA's ACT layout)
ACTION, QPOS, QVEL = "action", f"{OBSERVATIONS}/qpos", f"{OBSERVATIONS}/qvel"
NEEDS = f"every episode needs /{ACTION} and /{QPOS}"


def stream_path(group: str, name: str) -> str:
    """The path of stream ``name`` of ``group`` (images, tactile, tactile_background or force)."""
    return f"{OBSERVATIONS}/{group}/{name}"


def open_episode(path: Path) -> h5py.File:
    """``path`` opened read-only; a file that is not HDF5 (or is truncated) is a ValueError naming it."""
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path}: not a readable HDF5 episode file ({exc})") from None


def streams(f: h5py.File, group: str) -> list[str]:
    """Names under ``/observations/<group>`` (sorted; [] when the group is absent)."""
    where = f"{OBSERVATIONS}/{group}"
    return sorted(f[where].keys()) if where in f else []


def _require(f: h5py.File, path: Path, key: str) -> h5py.Dataset:
    if key not in f:
        raise ValueError(f"{path.name}: no /{key} ({NEEDS})")
    return f[key]


def check_finite(where: str, values: np.ndarray) -> None:
    """Refuse per-frame values (T, ...) holding NaN or inf, naming ``where`` and the first such frame."""
    values = np.asarray(values)
    ok = np.isfinite(values.reshape(len(values), -1)).all(axis=1)
    if not ok.all():
        raise ValueError(f"{where} holds NaN or inf (first at frame {int(np.flatnonzero(~ok)[0])})")


def check_newtons(where: str, force: np.ndarray) -> None:
    """Refuse forces (...) beyond MAX_PLAUSIBLE_FORCE_N, most likely logged in mN; ``where`` names them."""
    peak = float(np.abs(force).max(initial=0.0))
    if peak > MAX_PLAUSIBLE_FORCE_N:
        raise ValueError(f"{where} reaches {peak:.4g}, above {MAX_PLAUSIBLE_FORCE_N:g} N: are the labels in mN? "
                         "Labels must be in N")


def check_force_labels(where: str, force: np.ndarray) -> None:
    """Refuse labels (T, 3) that are not finite, look like mN, or press with a negative Fz; ``where`` names them."""
    check_finite(where, force)
    check_newtons(where, force)
    contact = np.linalg.norm(force, axis=1) > CONTACT_N
    if contact.any() and float(np.median(force[contact, 2])) < 0:
        raise ValueError(f"{where} has a negative median Fz in contact; the convention is Fz > 0 pressing "
                         "(sensor frame): flip the sign of the labels")


def _check_shapes(f: h5py.File, path: Path) -> None:
    """Every stream has its layout's number of axes (and 3 colour or force components), so that nothing downstream
    fails on a transposed, flattened or scalar array."""
    expected = {key: SHAPES["vector"] for key in (ACTION, QPOS, QVEL) if key in f}
    expected.update({stream_path(g, s): SHAPES[g] for g in (*PER_FRAME_GROUPS, "tactile_background")
                     for s in streams(f, g)})
    for key, (ndim, last, text) in expected.items():
        shape = f[key].shape
        if shape is None or len(shape) != ndim or (last is not None and shape[-1] != last):
            raise ValueError(f"{path.name}: /{key} has shape {shape}; expected {text}")
        if ndim >= 3 and f[key].dtype != np.uint8:
            raise ValueError(f"{path.name}: /{key} is {f[key].dtype}; images are stored as uint8 RGB")
    for s in streams(f, "tactile_background"):
        frame = f[stream_path("tactile", s)].shape[1:] if stream_path("tactile", s) in f else None
        if frame is not None and f[stream_path("tactile_background", s)].shape != frame:
            raise ValueError(f"{path.name}: /{stream_path('tactile_background', s)} has shape "
                             f"{f[stream_path('tactile_background', s)].shape}; expected its frames' {frame}")


def layout(f: h5py.File, cameras, sensors) -> dict[str, tuple]:
    """The shapes, without the frame axis (a background's whole shape), of the actions, qpos and the streams of
    the chosen ``cameras`` and tactile ``sensors``: what every episode of a folder shares, so that its frames stack
    into one batch (a stream nobody reads may differ)."""
    keys = [k for k in (ACTION, QPOS) if k in f] + [stream_path("images", c) for c in cameras]
    keys += [stream_path(g, s) for g in ("tactile", "tactile_background", "force") for s in sensors]
    return {k: tuple(f[k].shape if "tactile_background" in k else f[k].shape[1:]) for k in keys if k in f}


def check_same_layout(path: Path, first: Path, expected: dict[str, tuple], found: dict[str, tuple]) -> None:
    """``path``'s streams have the shapes of ``first``'s (``layout``), for the streams both record."""
    for key in sorted(expected.keys() & found.keys()):
        if expected[key] != found[key]:
            raise ValueError(f"{path.name}: /{key} is {found[key]} per frame, {first.name}'s is {expected[key]}; "
                             "every episode of a folder needs the same shapes")


def check_episode(f: h5py.File, path: Path) -> int:
    """Validate one open episode file (see the module docstring); returns its number of frames T."""
    qpos = _require(f, path, QPOS)
    action = _require(f, path, ACTION)
    _check_shapes(f, path)
    T = int(qpos.shape[0])
    if T == 0:
        raise ValueError(f"{path.name}: /{QPOS} has 0 frames; an episode needs at least one")
    per_frame = {ACTION: action, QPOS: qpos}
    if QVEL in f:
        per_frame[QVEL] = f[QVEL]
    for group in PER_FRAME_GROUPS:
        per_frame.update({stream_path(group, s): f[stream_path(group, s)] for s in streams(f, group)})
    wrong = {k: int(d.shape[0]) for k, d in per_frame.items() if d.shape[0] != T}
    if wrong:
        key, n = next(iter(wrong.items()))
        raise ValueError(f"{path.name}: /{key} has {n} frames, /{QPOS} has {T}; every per-frame "
                         "stream of an episode needs the same length")
    for key in (ACTION, QPOS):
        check_finite(f"{path.name}: /{key}", per_frame[key][()])
    for name in streams(f, "force"):
        check_force_labels(f"{path.name}: /{stream_path('force', name)}", f[stream_path("force", name)][()])
    return T


def check_same_streams(path: Path, first: Path, group: str, expected: list[str], found: list[str],
                       exact: bool) -> None:
    """``path`` records the ``expected`` streams of ``group`` (exactly, or at least when a subset was chosen)."""
    missing = sorted(set(expected) - set(found))
    extra = sorted(set(found) - set(expected)) if exact else []
    if missing or extra:
        what = f"lacks {group}/{missing[0]}" if missing else f"has {group}/{extra[0]}"
        raise ValueError(f"{path.name} {what}, unlike {first.name} ({group}: {expected}); every episode of a "
                         "folder must record the same streams")
