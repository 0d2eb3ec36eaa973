#!/usr/bin/env bash
# Sourced by the scripts a device-tool call runs on the lent GPU machine (Python 3.12 with torch, no registry):
#   source benchmarks/gpu_setup.sh LOG [COMMIT TREE]
# with COMMIT TREE (`git rev-parse --short HEAD HEAD^{tree}` here), exports CONTROLTAC_VERIFIED_COMMIT=COMMIT where
# the copy's files hash to TREE (the device's copy of .git is stale; benchmarks.common names that commit), installs
# the wheels that machine lacks from .whl/ (carried: the device tool's `carry: [".whl"]`) into a fresh
# /tmp/site, puts this checkout and them on PYTHONPATH, and returns 5 (after three lines of LOG) where the
# project's imports still fail. Fetch the wheels here first, into the ignored .whl/ (huggingface_hub stays the
# machine's own: the newer one needs httpx2, which that machine lacks):
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \
#     diffusers==0.42.1 pydantic==2.13.4 pydantic_core==2.46.4 annotated-types==0.7.0 typing-inspection==0.4.2 \
#     importlib_metadata==10.2.0 typing_extensions==4.16.0
LOG=${1:-/dev/stderr}
if [ -n "${3:-}" ]; then  # the files here against commit $2's tree, .git's own exclusions and the carried aside
  here=$(export GIT_INDEX_FILE=/tmp/gpu_setup.index; rm -f $GIT_INDEX_FILE
         git add -A . && git rm -rq --cached --ignore-unmatch .whl .baseline && git write-tree)
  [ "$here" = "$3" ] && export CONTROLTAC_VERIFIED_COMMIT=$2
fi
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
if [ -d .whl ]; then
  rm -rf /tmp/site  # a warm machine keeps the last call's /tmp
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || return 3
  export PYTHONPATH="/tmp/site:$PYTHONPATH"
fi
python3 -c "import torch, diffusers, pydantic, cv2; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())" \
  >> "$LOG" 2>&1 || { echo "imports failed:"; tail -3 "$LOG"; return 5; }
