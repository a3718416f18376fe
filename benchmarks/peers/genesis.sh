#!/usr/bin/env bash
# Peer benchmark: our MLS-MPM water (sim.engine.mpm.MPMSolver) against Genesis's MPM Liquid on the same 3D
# dam break (benchmarks/peers/dambreak_common.py), particle-substeps/s side by side plus the surge
# front of both over time.
#
#   bash benchmarks/peers/genesis.sh [--sizes "0.01 0.005"] [--arch cpu|gpu] [--threads 2]
#        [--steps 0] [--envs "1"] [--rounds 2] [--batch-steps 300] [--max-particles 200000]
#        [--out benchmarks/results/peers_genesis.json]
#
# Genesis pins its own Taichi fork (Quadrants) and many heavy packages, so it is kept out of the
# project's dependencies: it lives in its own virtual environment, .cache/peers/genesis-venv (made
# here when missing: torch first, pinned, so that pip does not pull a multi-GB CUDA build, then
# genesis-world, pinned). Our side runs in the caller's `python` (the project's, `pip install -e .`).
#
# Options
#   --sizes         grid spacings dx in m (each: dt = 2e-2 dx, 8 particles per cell)
#   --arch          cpu | gpu (gpu: a second venv, genesis-venv-cuda, with torch's CUDA build,
#                   which Genesis's GPU backend needs)
#   --threads N     CPU threads of both solvers: ours via Taichi's cpu_max_num_threads
#                   (TI_CPU_MAX_NUM_THREADS), Genesis via QD_NUM_THREADS (Genesis otherwise runs
#                   Quadrants on 1 thread on the CPU) and torch.set_num_threads
#   --steps N       substeps per B = 1 run (rounded up to frames of 10); 0 = the whole dam break to
#                   T = t sqrt(2g/a) = 3 (1080 substeps at 10 mm, 2150 at 5 mm)
#   --envs "1 8"    batch sizes B (Genesis: scene.build(n_envs=B)); B > 1 runs time --batch-steps
#                   substeps (their front is env 0's, the same scene as B = 1) and are skipped where
#                   B * particles > --max-particles
#   --rounds R      runs of each solver, alternating ours, genesis, ours, genesis, ...; best is kept
#   --out FILE      combined JSON (default benchmarks/results/peers_genesis.json); per-run JSONs and logs go
#                   to .cache/peers/genesis-runs/<time>/
set -euo pipefail

GENESIS_VERSION=1.4.5
TORCH_VERSION=2.13.0

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
HERE="$ROOT/benchmarks/peers"
PY="${PYTHON:-python}"
SIZES="0.01 0.005"
ARCH=cpu
THREADS=2
STEPS=0
ENVS="1"
ROUNDS=2
BATCH_STEPS=300
MAX_PARTICLES=""
OUT="$ROOT/benchmarks/results/peers_genesis.json"
CMDLINE="bash benchmarks/peers/genesis.sh $*"

while [[ $# -gt 0 ]]; do
  case "$1" in
    --sizes) SIZES="$2"; shift 2 ;;
    --arch) ARCH="$2"; shift 2 ;;
    --threads) THREADS="$2"; shift 2 ;;
    --steps) STEPS="$2"; shift 2 ;;
    --envs) ENVS="$2"; shift 2 ;;
    --rounds) ROUNDS="$2"; shift 2 ;;
    --batch-steps) BATCH_STEPS="$2"; shift 2 ;;
    --max-particles) MAX_PARTICLES="$2"; shift 2 ;;
    --out) OUT="$2"; shift 2 ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d'; exit 0 ;;
    *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
case "$ARCH" in cpu|gpu) ;; *) echo "--arch must be cpu or gpu" >&2; exit 2 ;; esac
if [[ -z "$MAX_PARTICLES" ]]; then
  if [[ "$ARCH" == cpu ]]; then MAX_PARTICLES=200000; else MAX_PARTICLES=100000000; fi
fi
[[ "$OUT" = /* ]] || OUT="$PWD/$OUT"
LOAD_START="$(cut -d' ' -f1-3 /proc/loadavg)"

# ------------------------------------------------------------------ Genesis virtual environment
if [[ "$ARCH" == cpu ]]; then VENV="$ROOT/.cache/peers/genesis-venv"; else VENV="$ROOT/.cache/peers/genesis-venv-cuda"; fi
GPY="$VENV/bin/python"
genesis_ok() { "$GPY" -c "import genesis, torch; assert genesis.__version__ == '$GENESIS_VERSION'" >/dev/null 2>&1; }
if ! genesis_ok; then
  echo "== setting up $VENV (torch==$TORCH_VERSION, genesis-world==$GENESIS_VERSION)"
  [[ -x "$GPY" ]] || "$PY" -m venv "$VENV"
  "$GPY" -m pip install -q --upgrade pip
  if [[ "$ARCH" == cpu ]]; then
    # the CPU build; torch's default Linux wheel is the multi-GB CUDA one
    "$GPY" -m pip install -q "torch==$TORCH_VERSION"
  else
    # Genesis's GPU backend needs torch with CUDA (gs.init(backend=gs.gpu) asks torch.cuda)
    PIP_FIND_LINKS="" "$GPY" -m pip install -q "torch==$TORCH_VERSION"
  fi
  "$GPY" -m pip install -q "genesis-world==$GENESIS_VERSION"
fi
if ! "$GPY" -c "import genesis" >/dev/null 2>&1; then
  # Genesis imports OpenCV, VTK and OpenGL bindings, which need these system libraries
  if [[ $(id -u) == 0 ]] && command -v apt-get >/dev/null; then
    echo "== installing system libraries Genesis needs"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
      libgl1 libegl1 libglib2.0-0 libxrender1 libxext6 libsm6 libgomp1 >/dev/null
  fi
  "$GPY" -c "import genesis" || { echo "genesis does not import in $VENV" >&2; exit 1; }
fi

# ------------------------------------------------------------------ runs, alternating
RAW="$ROOT/.cache/peers/genesis-runs/$(date +%Y%m%d-%H%M%S)"
mkdir -p "$RAW"
echo "== per-run JSONs and logs in $RAW"
expected() { "$PY" -c "import sys; sys.path.insert(0, '$HERE'); import dambreak_common as C; print(C.expected_particles($1))"; }
run_one() {  # solver dx B round
  local solver=$1 dx=$2 B=$3 r=$4 steps=$STEPS py=$PY
  [[ "$B" -gt 1 ]] && steps=$BATCH_STEPS
  [[ "$solver" == genesis ]] && py=$GPY
  local tag="${solver}_dx${dx}_B${B}_r${r}"
  echo "-- $tag ($(cut -d' ' -f1-3 /proc/loadavg))"
  (cd "$ROOT" && PYTHONUNBUFFERED=1 "$py" "$HERE/dambreak_${solver}.py" --dx "$dx" --envs "$B" --arch "$ARCH" \
     --threads "$THREADS" --steps "$steps" --out "$RAW/$tag.json" >"$RAW/$tag.log" 2>&1) \
    || { echo "   FAILED, see $RAW/$tag.log"; tail -5 "$RAW/$tag.log"; return 0; }
  grep -E "^(ours|genesis) " "$RAW/$tag.log" | sed 's/^/   /'
}
T0=$(date +%s)
for dx in $SIZES; do
  n=$(expected "$dx")
  for B in $ENVS; do
    if [[ "$B" -gt 1 && $((B * n)) -gt "$MAX_PARTICLES" ]]; then
      echo "-- skip dx=$dx B=$B: $((B * n)) particles > --max-particles $MAX_PARTICLES"; continue
    fi
    for r in $(seq 1 "$ROUNDS"); do
      run_one ours "$dx" "$B" "$r"
      run_one genesis "$dx" "$B" "$r"
    done
  done
done
RUNS_S=$(( $(date +%s) - T0 ))
echo "== runs took $RUNS_S s"
mkdir -p "$(dirname "$OUT")"
"$PY" "$HERE/combine_genesis.py" --raw "$RAW" --out "$OUT" --loadavg-start "$LOAD_START" --command "$CMDLINE" \
  --runs-seconds "$RUNS_S"
