#!/usr/bin/env bash
# When run.sh has finished its 7000 steps: test the scan-fitting model and ship it with its card, then run every
# user-facing measurement on it. Each step skips itself when its output is there, so the script can be rerun
# after an interruption. One thread per job (the numbers of experiments/ were all made that way), two jobs at a
# time: the test sets and the card in one, the user-facing measurements in the other.
#   bash experiments/scan_model/finish.sh [CKPT]      # default: outputs/scan_model/run3/checkpoints/last.ckpt
# Writes: outputs/scan_model/eval (arteq.eval: every full-surface and single-view test set of the all-ages
# body, per age band and build), src/arteq/pretrained/$NAME.{ckpt,md} (weights and card),
# experiments/scan_model/final/ (user-scan suite, single-view table, check calibration on both seeds). Switching arteq-fit's
# default to it is a decision on those numbers, made by hand (src/arteq/pretrained/__init__.py).
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
CKPT=${1:-outputs/scan_model/run3/checkpoints/last.ckpt}
NAME=${NAME:-anny_scan}
EVAL=${EVAL:-outputs/scan_model/eval}
OUT=experiments/scan_model/final
PY=.venv/bin/python
[ -f "$CKPT" ] || { echo "finish.sh: $CKPT: no such checkpoint (run experiments/scan_model/run.sh first)" >&2; exit 2; }
mkdir -p "$OUT"
# a private copy: the run's checkpoints rotate while a run is live
if [ "$CKPT" != outputs/scan_model/final.ckpt ]; then
  cp "$CKPT" outputs/scan_model/final.ckpt.tmp && mv outputs/scan_model/final.ckpt.tmp outputs/scan_model/final.ckpt
fi
CKPT=outputs/scan_model/final.ckpt

(
echo "== test sets (full surfaces and single views, all-ages shapes) -> $EVAL"
[ -f "$EVAL/metrics.json" ] || $PY -m arteq.eval ckpt_path=$CKPT body_model=anny_allages data.shape_prior=allages data.eval_augment=so3 \
    'data.view_splits=[front,side,back,top]' output_dir="$EVAL"

echo "== weights and card -> src/arteq/pretrained/$NAME"
[ -f "src/arteq/pretrained/$NAME.md" ] || $PY -m arteq.pretrained.card export $CKPT --name "$NAME" --metrics-from "$EVAL" \
 --command "nohup bash experiments/scan_model/run.sh > outputs/scan_model/run3.log 2>&1 &   (resumed across sessions from experiments/pretrained/scan_local_resume.ckpt)" \
 --command "python -m arteq.eval ckpt_path=<run3 last checkpoint> body_model=anny_allages data.shape_prior=allages data.eval_augment=so3 'data.view_splits=[front,side,back,top]'   (the test metrics below; experiments/scan_model/finish.sh)" \
 --training "stage 2 for 7000 steps (14 epochs of 500), batch 8, 500 points, lr 1e-3 cosine, seed 0, one thread (two for steps 5275-7000), from the research model anny22_local's weights (its shape head's output layer fresh: 16 betas here); the all-ages body and shapes; training poses: everyday (half widened) 40 %, the hard OOD sampler 40 %, everyday with one / two OOD limbs 10 % / 10 %; any orientation; a quarter of the clouds single-view depth scans. Resumed across sessions (experiments/scan_model/README.md)." \
 --hardware "2-core AMD EPYC VM (KVM), 24 GiB, torch 2.13.0+cpu, one or two threads, no GPU" \
 --notes "The scan-fitting model (issue 19): the part-local network (model=arteq_local) on the all-ages body (children to elderly, extreme builds), trained on every pose sampler of the project and on single-view scans. Held out: the test sets (own seeds), the user-scan suite's acrobatic templates and bodies (experiments/fitting/user_scans.py), the single-view test sets. The mix contains the samplers of test_ood, test_ood_limb1 and test_ood_limb2: those are seen distributions for this model (new poses, not new kinds of pose)."
) > outputs/scan_model/finish_eval.log 2>&1 &
A=$!
(
echo "== user-scan suite -> $OUT/user_scans.md"
[ -f "$OUT/user_scans.md" ] || $PY experiments/fitting/user_scans.py --ckpt $CKPT --threads 1 \
    --out "$OUT/user_scans.md" --json "$OUT/user_scans.json"

echo "== single-view scans -> $OUT/single_view"
[ -f "$OUT/single_view/refine_partial.json" ] || $PY experiments/single_view/run.py --arm refine_partial --ckpt $CKPT \
    --threads 1 --out "$OUT/single_view"
$PY experiments/single_view/run.py --table --out "$OUT/single_view"

echo "== check calibration -> $OUT/check_calibration.json"
[ -f "$OUT/check_calibration.json" ] || $PY experiments/fitting/check_calibration.py --model $CKPT \
    --out "$OUT/check_calibration.json" > "$OUT/check_calibration.log"
[ -f "$OUT/check_calibration_seed1.json" ] || $PY experiments/fitting/check_calibration.py --model $CKPT --seed 1 \
    --out "$OUT/check_calibration_seed1.json" > "$OUT/check_calibration_seed1.log"
) > outputs/scan_model/finish_user.log 2>&1 &
B=$!
echo "finish.sh: two jobs, logs outputs/scan_model/finish_{eval,user}.log"
wait $A
wait $B
echo "finish.sh: done; compare $OUT with experiments/fitting/ (anny22) before switching arteq-fit's default"
