#!/usr/bin/env bash
# Prepare the next scan-model training call on a lent GPU machine (experiments/scan_model/README.md, "For the
# next GPU run"), from this machine, then print the device command.
#   bash experiments/scan_model/gpu_prep.sh [OVERRIDES...]
# 1. .whl/: the wheels the GPU machine lacks (hydra-core, omegaconf, antlr4, roma, trimesh), at this venv's
#    versions, for its Python 3.12 (needs the package registry; ignored by git, carried by the call);
# 2. .gpu/cache: the all-ages body, its finger curl and the validation set (the GPU machine has no anny), built
#    by a tiny CPU run of gpu_run.py with the same overrides, which also checks that the config composes and
#    trains (its files in /tmp/gpu_prep_check);
# 3. prints the call: `run` with carry [.whl, .gpu] and the command below.
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=${PY:-.venv/bin/python}
INIT=${INIT:-experiments/pretrained/scan_gpu7_resume.ckpt}
BUDGET=${BUDGET:-360}
if [ $# -eq 0 ]; then
  set -- seed=3 data.train_epoch_offset=18 data.hand_curl=0.3 \
    'data.train_pose_mix={id:0.35,ood:0.2,athletic:0.1,athletic_spine:0.15,limb1:0.1,limb2:0.1}'
fi
grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo /.whl/ >> .git/info/exclude
mkdir -p .whl
ver() { "$PY" -c "import importlib.metadata as m; print(m.version('$1'))"; }
"$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \
  "hydra-core==$(ver hydra-core)" "omegaconf==$(ver omegaconf)" "roma==$(ver roma)" "trimesh==$(ver trimesh)"
"$PY" -m pip wheel -q --no-deps -w .whl "antlr4-python3-runtime==$(ver antlr4-python3-runtime)"
export ARTEQ_CACHE_DIR=.gpu/cache
"$PY" -c "from arteq.body.hands import ensure_hands; ensure_hands('anny_allages')"
OMP_NUM_THREADS=2 "$PY" experiments/scan_model/gpu_run.py --device cpu --batch 2 --budget 20 --probe-steps 2 \
  --init "$INIT" --lr 1.5e-4 --out /tmp/gpu_prep_check --run /tmp/gpu_prep_check/run "$@"
"$PY" -c "import json, sys; r = json.load(open('/tmp/gpu_prep_check/gpu_run.json')); sys.exit(r['train_rc'] != 0)" \
  || { echo "gpu_prep: the CPU check did not train (/tmp/gpu_prep_check/train.log)" >&2; exit 1; }
du -sh .whl .gpu
q=""; for o in "$@"; do q+=" '$o'"; done
cat <<CMD
device call: carry [".whl", ".gpu"], timeout_s 600, command:
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:\$PWD/src || exit; ARTEQ_CACHE_DIR=.gpu/cache python3 experiments/scan_model/gpu_run.py --budget $BUDGET --init $INIT --lr 1.5e-4 --out \$OUT$q
CMD
