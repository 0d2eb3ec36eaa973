"""The names of the observation streams in each vocabulary that names them, and the mappings between them.

A stream (the arm's state, a camera, a tactile sensor's image, its no-contact background, its force label) is
named in three vocabularies; camera ``wrist`` and tactile sensor ``left``::

    LOOP     the scene and the control loop    qpos               images/wrist              tactile/left
             (observation dicts)                                  tactile_background/left   force/left
    HDF5     our datasets' items, ACT's        observation.qpos   observation.images.wrist  observation.tactile.left
             batches and the augment caches                       observation.tactile_background.left
                                                                  observation.force.left
    LEROBOT  LeRobot datasets' features        observation.state  observation.images.wrist  observation.images.left
                                                                  observation.left.force

LeRobot records a tactile sensor as a camera and no background. A LOOP or HDF5 key names its stream by all that
follows its prefix (``tactile/gs.left`` and ``observation.tactile.gs.left``: sensor ``gs.left``); a LeRobot
feature by its last dotted part (``observation.images.gs.left``: ``left``). These names are file formats
(datasets, caches, checkpoints' inputs): they stay as they are. Torch-free and dependency-free, so that every
floor (library, policies, hardware, envs) imports it.
"""

from __future__ import annotations

LOOP, HDF5, LEROBOT = "loop", "hdf5", "lerobot"
VOCABULARIES = (LOOP, HDF5, LEROBOT)

LOOP_STATE = "qpos"
LOOP_IMAGES = "images/"
LOOP_TACTILE = "tactile/"
LOOP_BACKGROUND = "tactile_background/"
LOOP_FORCE = "force/"

HDF5_STATE = "observation.qpos"
HDF5_IMAGES = "observation.images."
HDF5_TACTILE = "observation.tactile."
HDF5_BACKGROUND = "observation.tactile_background."
HDF5_FORCE = "observation.force."

LEROBOT_STATE = "observation.state"
LEROBOT_IMAGES = "observation.images."
LEROBOT_FORCE = "observation.{}.force"  # the default force feature of tactile camera ``{}`` (its lerobot_name)

STATE, IMAGE, TACTILE, BACKGROUND, FORCE = "state", "image", "tactile", "background", "force"  # kinds of stream

# the naming rule of a tactile image's force label and background: its first TACTILE_WORD replaced
TACTILE_WORD = "tactile"
RULE_WORDS = {FORCE: "force", BACKGROUND: "tactile_background"}
_PREFIXES = {
    LOOP: {IMAGE: LOOP_IMAGES, TACTILE: LOOP_TACTILE, BACKGROUND: LOOP_BACKGROUND, FORCE: LOOP_FORCE},
    HDF5: {IMAGE: HDF5_IMAGES, TACTILE: HDF5_TACTILE, BACKGROUND: HDF5_BACKGROUND, FORCE: HDF5_FORCE},
}
_STATES = {LOOP: LOOP_STATE, HDF5: HDF5_STATE}


def _vocabulary(vocabulary: str) -> str:
    if vocabulary not in VOCABULARIES:
        raise ValueError(f"vocabulary: expected one of {list(VOCABULARIES)}, got {vocabulary!r}")
    return vocabulary


def _key(kind: str, name: str, vocabulary: str) -> str:
    if _vocabulary(vocabulary) != LEROBOT:
        return _PREFIXES[vocabulary][kind] + name
    if kind == BACKGROUND:
        raise ValueError(f"LeRobot datasets record no tactile background (sensor {name!r})")
    return LEROBOT_FORCE.format(name) if kind == FORCE else LEROBOT_IMAGES + name


def image_key(cam: str, vocabulary: str) -> str:
    """Camera ``cam``: ``images/wrist`` (LOOP), ``observation.images.wrist`` (HDF5 and LEROBOT)."""
    return _key(IMAGE, cam, vocabulary)


def tactile_key(sensor: str, vocabulary: str) -> str:
    """Tactile image of ``sensor``: ``tactile/left`` (LOOP), ``observation.tactile.left`` (HDF5),
    ``observation.images.left`` (LEROBOT: a camera)."""
    return _key(TACTILE, sensor, vocabulary)


def background_key(sensor: str, vocabulary: str) -> str:
    """No-contact image of ``sensor``: ``tactile_background/left`` (LOOP), ``observation.tactile_background.left``
    (HDF5); LeRobot records none (ValueError)."""
    return _key(BACKGROUND, sensor, vocabulary)


def force_key(sensor: str, vocabulary: str) -> str:
    """Force label [Fx, Fy, Fz] N of ``sensor``: ``force/left`` (LOOP), ``observation.force.left`` (HDF5),
    ``observation.left.force`` (LEROBOT, the default feature)."""
    return _key(FORCE, sensor, vocabulary)


def parse(key: str) -> tuple[str, str, str | None]:
    """(vocabulary, kind, name) of a LOOP or HDF5 key; kind is STATE (name None), IMAGE, TACTILE, BACKGROUND or
    FORCE: ``tactile/gs.left`` -> (LOOP, TACTILE, "gs.left"). A camera ``observation.images.<c>`` reads as HDF5
    (LeRobot spells it alike). ValueError naming any other key."""
    for vocabulary in (LOOP, HDF5):
        if key == _STATES[vocabulary]:
            return vocabulary, STATE, None
        for kind, prefix in _PREFIXES[vocabulary].items():
            if key.startswith(prefix) and len(key) > len(prefix):
                return vocabulary, kind, key[len(prefix):]
    raise ValueError(f"{key!r} is not a stream key (e.g. {LOOP_TACTILE}left or {HDF5_TACTILE}left)")


def sensor_of(key: str) -> str:
    """The sensor (or camera) a LOOP or HDF5 key names: ``tactile/left``, ``observation.force.gs.left`` ->
    ``left``, ``gs.left``. ValueError naming a key that names none (a state key, an unknown key)."""
    name = parse(key)[2]
    if name is None:
        raise ValueError(f"{key!r} is the arm's state, not a sensor's stream")
    return name


def loop_to_hdf5(key: str) -> str:
    """HDF5 item key of LOOP key ``key`` (what a policy's batch holds of an observation): ``qpos`` ->
    ``observation.qpos``, ``tactile/left`` -> ``observation.tactile.left``; ValueError naming any other key."""
    vocabulary, kind, name = parse(key)
    if vocabulary != LOOP:
        raise ValueError(f"{key!r} is not a {LOOP} key")
    return HDF5_STATE if kind == STATE else _PREFIXES[HDF5][kind] + name


def lerobot_name(key: str) -> str:
    """The stream name of a LeRobot feature: its last dotted part (``observation.images.gelsight_left`` ->
    ``gelsight_left``)."""
    return key.rsplit(".", 1)[-1]


def lerobot_to_hdf5(key: str, tactile: bool = False) -> str:
    """HDF5 item key of LeRobot feature ``key``: ``observation.state`` -> ``observation.qpos``; a camera (any
    other feature) -> ``observation.images.<n>``, or ``observation.tactile.<n>`` where ``tactile``, n its
    lerobot_name (``observation.images.gelsight_left`` -> ``observation.tactile.gelsight_left``)."""
    if key == LEROBOT_STATE:
        return HDF5_STATE
    return (tactile_key if tactile else image_key)(lerobot_name(key), HDF5)


def looks_tactile(key: str) -> bool:
    """Whether ``key`` names a tactile image by the naming rule: it holds "tactile" and is no background
    (``observation.tactile.left``, ``tactile/left``, ``observation.images.tactile_left``)."""
    return TACTILE_WORD in key and RULE_WORDS[BACKGROUND] not in key


def rule_key(key: str, kind: str) -> str | None:
    """The FORCE label or BACKGROUND key of tactile image ``key`` by the naming rule, its first "tactile"
    replaced: ``observation.tactile.left`` -> ``observation.force.left`` / ``observation.tactile_background.left``,
    ``tactile/left`` -> ``force/left``; None where ``key`` does not look tactile."""
    if kind not in RULE_WORDS:
        raise ValueError(f"kind: expected one of {list(RULE_WORDS)}, got {kind!r}")
    return key.replace(TACTILE_WORD, RULE_WORDS[kind], 1) if looks_tactile(key) else None
