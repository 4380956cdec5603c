#!/usr/bin/env bash
# The prepared GPU run (issue 42): on a lent GPU machine, from the repository root, with .gpu/
# carried (make gpu-pack made it here):
#   make gpu-train MINUTES=8          # packed checkpoints, train.log and summary.json in $OUT
# The machine has torch but not pydantic, laspy, lazrs or plyfile: they come from the wheels
# in .gpu/wheels, installed into /tmp/site without touching the machine's own packages.
set -euo pipefail
cd "$(dirname "$0")/.."
MINUTES="${1:-8}"
PY="${PYTHON:-python3}"
DATA="${GPU_DATA:-.gpu/data}"
DEST="${OUT:-runs/gpu}"
SAVE="${SAVE_MINUTES:-2}"
if [ ! -f "$DATA/manifest.json" ]; then
  echo "no training data in $DATA: run 'make gpu-pack' here and carry .gpu" >&2
  exit 2
fi
if ! "$PY" -c "import pydantic, laspy, plyfile" 2>/dev/null; then
  if ! ls .gpu/wheels/*.whl >/dev/null 2>&1; then
    echo "pydantic, laspy or plyfile missing and no wheels in .gpu/wheels: run 'make gpu-pack'" >&2
    exit 2
  fi
  "$PY" -m pip install -q --no-index --no-deps --target /tmp/site .gpu/wheels/*.whl
  export PYTHONPATH="/tmp/site:${PYTHONPATH:-}"
fi
export PYTHONPATH="$PWD:${PYTHONPATH:-}"
exec "$PY" -m jointseg.training.prepared run --data "$DATA" --out "$DEST" \
  --minutes "$MINUTES" --save-minutes "$SAVE"
