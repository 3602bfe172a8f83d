#!/usr/bin/env bash
# The GPU figures of docs/performance.md ("A policy per backend"), in one run on a lent GPU machine
# (about 8 minutes on one H200, and at most 4 for the flood fill's step). Results go to $OUT (default benchmarks/results), one JSON per figure:
#
#   bash benchmarks/gpu.sh                 # on a GPU machine with jaxapf installed
#   OUT=/tmp/gpu bash benchmarks/gpu.sh    # elsewhere
#
# A machine without network (the lent H200) installs the wheels carried in .whl/ first (what it lacks:
# see /work/.library/device/README.md). Each step is bounded by `timeout`, so one slow step leaves the others'
# records. SMOKE=1 shrinks every step to a few fields: a check of the script on a CPU, not a figure.
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-benchmarks/results}
PY=${PYTHON:-python3}  # the interpreter with jaxapf's dependencies (PYTHON=... to choose another)
mkdir -p "$OUT"
if compgen -G ".whl/*.whl" > /dev/null; then
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    && export PYTHONPATH="/tmp/site:$PWD${PYTHONPATH:+:$PYTHONPATH}" || exit 1
else
  export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
fi
export PYTHONUNBUFFERED=1
"$PY" -c "import jax; print(jax.__version__, jax.devices())"
if [ "${SMOKE:-0}" = 1 ]; then  # sweeps/quick.toml: short episodes, a small MPC
  QUICK="--spec sweeps/quick.toml --fields 8 --repeats 1"; LARGE="--spec sweeps/quick.toml --fields 16 --repeats 1"
  FILL="--fields 8 --batch 8"
else
  QUICK=""; LARGE="--fields 8192"; FILL="--fields 2048 --batch 512"
fi

# the quick start (6,144 episodes): cold and warm, under both policies, phase by phase
timeout 240 "$PY" benchmarks/policy.py $QUICK --phases --json "$OUT/policy-gpu.json"
# the 98,304-episode sweep: compare-small at 8,192 fields per family, the accelerator's policy
timeout 240 "$PY" benchmarks/policy.py $LARGE --policy accelerator --json "$OUT/policy-gpu-large.json"
# the oracle's static test as a JAX flood fill on the device, against the certificates on the host
timeout 240 "$PY" benchmarks/oracle_fill.py $FILL --json "$OUT/oracle-fill-gpu.json"
# compare and tune on the same path, cold compilation cache
export XDG_CACHE_HOME=$(mktemp -d)
for step in "compare sweeps/compare-quick.toml" "tune sweeps/tune-tiny.toml"; do
  name=${step%% *}
  start=$(date +%s.%N)
  if [ "${SMOKE:-0}" = 1 ]; then  # the command is there; running it is the figure
    "$PY" -m jaxapf ${step%% *} --help > /dev/null; rc=$?
  else
    timeout 150 "$PY" -m jaxapf $step --out "$(mktemp -d)/$name" > /dev/null; rc=$?
  fi
  end=$(date +%s.%N)
  "$PY" - "$OUT/$name-gpu.json" "$step" "$start" "$end" "$rc" <<'EOF'
import json, sys
from jaxapf.bench.engine import environment
path, step, start, end, rc = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5])
json.dump({"command": "jaxapf " + step, "cold_s": round(end - start, 1), "rc": rc,
           "environment": environment("float32")}, open(path, "w"), indent=1)
EOF
done
ls -l "$OUT"
