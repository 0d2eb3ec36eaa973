#!/usr/bin/env bash
# One entry point that sets up a fresh machine and then runs a job.
#   ./run.sh [OPTIONS]  the main job on the embedded default (see README; --help lists the options)
#   ./run.sh test       the test suite (what CI runs)
#   ./run.sh <cmd...>   any command inside the set-up environment
set -euo pipefail
cd "$(dirname "$0")"
PY=${PYTHON:-python3}
export MUJOCO_GL=${MUJOCO_GL:-egl}
export PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-$MUJOCO_GL}

requirements_met() {
    # exit 0 when every requirement of pyproject.toml (its core and the all and dev extras) is installed at a
    # version it accepts; anything it cannot tell (no tomllib or packaging) counts as not met
    "$PY" - <<'EOF' 2>/dev/null
import sys, tomllib
from importlib import metadata
from packaging.requirements import Requirement

project = tomllib.load(open("pyproject.toml", "rb"))["project"]
todo, seen = list(project["dependencies"]), set()
todo += [r for extra in ("all", "dev") for r in project["optional-dependencies"][extra]]
while todo:
    req = Requirement(todo.pop())
    if req.marker is not None and not req.marker.evaluate({"extra": ""}):
        continue
    if req.name == project["name"]:  # the project's own extras, e.g. controltac-il[ur,sim]
        todo += [r for extra in req.extras - seen for r in project["optional-dependencies"][extra]]
        seen |= req.extras
        continue
    try:
        ok = req.specifier.contains(metadata.version(req.name), prereleases=True)
    except metadata.PackageNotFoundError:
        ok = False
    if not ok:
        sys.exit(1)
EOF
}

setup() {
    # torch: keep whatever the user has (e.g. a CUDA build); on a machine without one install the CPU build,
    # because PyPI's Linux `torch` pulls several GB of CUDA wheels: on Linux from PyTorch's CPU index (offline,
    # pip falls back to a local wheel after its retries), elsewhere PyPI's wheel is the CPU one.
    if ! "$PY" -c "import torch" 2>/dev/null; then
        echo "[setup] installing torch 2.13.0 (CPU build)"
        if [ "$(uname -s)" = Linux ]; then
            "$PY" -m pip install -q "torch==2.13.0+cpu" --extra-index-url https://download.pytorch.org/whl/cpu
        else
            "$PY" -m pip install -q torch==2.13.0
        fi
    fi
    # headless OpenGL for MuJoCo's renderer (Debian/Ubuntu); skipped when present.
    if [ "$MUJOCO_GL" = egl ] && ! ldconfig -p 2>/dev/null | grep -q libEGL.so.1; then
        if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
            echo "[setup] installing libegl1 for headless rendering"
            (apt-get update -qq && apt-get install -y -qq libegl1 libgl1 >/dev/null) || true
        fi
    fi
    # earlier versions of this project installed opencv-contrib-python-headless; two cv2 distributions in one
    # environment overwrite each other's files, so it gives way to LeRobot's opencv-python-headless
    if "$PY" -m pip show opencv-contrib-python-headless >/dev/null 2>&1; then
        echo "[setup] replacing opencv-contrib-python-headless by opencv-python-headless"
        "$PY" -m pip uninstall -y -q opencv-contrib-python-headless
        "$PY" -m pip install -q --force-reinstall --no-deps "opencv-python-headless>=4.9"
    fi
    local stamp=".setup-stamp"
    local want
    want=$(sha1sum < pyproject.toml | cut -d' ' -f1)
    if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ] || ! "$PY" -c "import controltac_il" 2>/dev/null; then
        # the build backend already installed (setuptools >= 68, pyproject's requirement) builds the editable
        # wheel in place: 19 s -> 13 s on the 2-core machine, no isolated environment to provision
        local isolation=()
        if "$PY" -c "import sys, setuptools; sys.exit(int(setuptools.__version__.split('.')[0]) < 68)" 2>/dev/null; then
            isolation=(--no-build-isolation)
        fi
        # where every requirement is already met (a fresh clone in a set-up environment, as in CI) only the
        # project itself is installed: 14 s -> 4.4 s on the 2-core machine (2026-11-29)
        if requirements_met; then
            echo "[setup] installing controltac-il (its requirements are met)"
            "$PY" -m pip install -q ${isolation[@]+"${isolation[@]}"} --no-deps -e .
        else
            echo "[setup] installing controltac-il and its dependencies"
            "$PY" -m pip install -q ${isolation[@]+"${isolation[@]}"} -e ".[all,dev]"
        fi
        echo "$want" > "$stamp"
    fi
}

setup
case "${1:-main}" in
    main) shift || true; exec "$PY" -m controltac_il "$@" ;;
    # two pytest-xdist workers, one torch thread each: 141 s -> 87 s idle on the 2-core machine (2026-11-26);
    # TEST_WORKERS=0 runs it in this process
    test) shift; exec "$PY" -m pytest -q -n "${TEST_WORKERS:-2}" "$@" ;;
    -*) exec "$PY" -m controltac_il "$@" ;;  # options of the main job, e.g. ./run.sh --sensor-only
    *) exec "$@" ;;
esac
