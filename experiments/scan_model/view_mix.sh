#!/usr/bin/env bash
# The share of single-view clouds in training (issue 20, item 4): controlled arms from the shipped scan model.
# Every arm starts from anny_scan's finished weights (experiments/pretrained/scan_local_resume.ckpt, run3 at
# stage-2 step 7000, trained with a quarter of its clouds single views) and trains stage 2 for 300 more steps
# (batch 8, lr 3e-4 cosine, a fresh optimizer, seed 0, 500 points, any orientation, the all-ages body and
# shapes, run3's pose mix), then is tested on 128 clouds of every full-surface test set and of the front,
# side, back and top-down view sets (the same clouds for every arm). Only the share of single views differs:
#   sv25  a quarter (run3's: the same training continued, the arms' baseline)
#   sv50  a half
#   sv75  three quarters
#   ood55 a quarter, with more joint-limit poses: pose mix {id:0.25,ood:0.55,limb1:0.1,limb2:0.1} (run3's: 0.4/0.4)
#   bash experiments/scan_model/view_mix.sh [ARM ...]     (one thread each, arms one after another)
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
INIT=${INIT:-experiments/pretrained/scan_local_resume.ckpt}
OUT=${OUT:-outputs/view_mix}
mkdir -p "$OUT"
COMMON=(+experiment=stage2 model=arteq_local body_model=anny_allages data.shape_prior=allages seed=0
        data.augment=so3 data.eval_augment=so3 data.train_size=2400 data.wide_poses=0.5
        'data.train_pose_mix={id:0.4,ood:0.4,limb1:0.1,limb2:0.1}' 'data.view_splits=[front,side,back,top]'
        stage1.ckpt="$INIT" trainer.max_epochs=1 model.optimizer.lr=3e-4 data.val_size=32 data.test_size=128
        mean_pose_baseline=false trainer.enable_progress_bar=false)
ARMS=("$@"); [ ${#ARMS[@]} -gt 0 ] || ARMS=(sv25 sv50 sv75)
for arm in "${ARMS[@]}"; do
  case $arm in
    sv25) extra=(data.single_view.prob=0.25) ;;
    sv50) extra=(data.single_view.prob=0.5) ;;
    sv75) extra=(data.single_view.prob=0.75) ;;
    ood55) extra=(data.single_view.prob=0.25 'data.train_pose_mix={id:0.25,ood:0.55,limb1:0.1,limb2:0.1}') ;;
    *) echo "unknown arm $arm" >&2; exit 2 ;;
  esac
  .venv/bin/python -m arteq.train "${COMMON[@]}" "${extra[@]}" hydra.run.dir="$OUT/$arm" > "$OUT/$arm.log" 2>&1
  cat "$OUT/$arm/metrics.md"
done
