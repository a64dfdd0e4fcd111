#!/usr/bin/env bash
# Controlled arms for the scan-fitting model (issue 19): which part of the training mix stops the part-local
# network from learning on the all-ages body. Every arm starts from the finished research model
# (experiments/pretrained/arteq_local_resume.ckpt, stage-2 step 6500, torso-frame sides; the shape head's
# output, 10 betas there and 16 here, starts fresh), then trains stage 2 for 300 steps (batch 8, lr 1e-3
# cosine, seed 0, 500 points, random orientations, all-ages body and shapes) and is tested on 128 clouds
# of every full-surface test set of the all-ages body (the same clouds for every arm).
#   mix   the scan run's mix: id 0.4 / hard ood 0.4 / one limb 0.1 / two limbs 0.1, a quarter single views
#   nosv  the same poses, full surfaces only
#   id    everyday poses only (half widened), full surfaces: the research recipe on the all-ages body
#   bash experiments/scan_model/arms.sh [ARM ...]     (one thread, arms one after another)
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
INIT=${INIT:-experiments/pretrained/arteq_local_resume.ckpt}
OUT=${OUT:-outputs/scan_arms}
mkdir -p "$OUT"
COMMON=(+experiment=stage2 model=arteq_local body_model=anny_allages data.shape_prior=allages seed=0
        data.augment=so3 data.eval_augment=so3 data.train_size=2400 data.wide_poses=0.5 'data.view_splits=[]'
        stage1.ckpt="$INIT" stage1.reinit_mismatched=true trainer.max_epochs=1 model.optimizer.lr=1e-3
        data.val_size=32 data.test_size=128 mean_pose_baseline=false trainer.enable_progress_bar=false)
ARMS=("$@"); [ ${#ARMS[@]} -gt 0 ] || ARMS=(mix nosv id)
for arm in "${ARMS[@]}"; do
  case $arm in
    mix)  extra=('data.train_pose_mix={id:0.4,ood:0.4,limb1:0.1,limb2:0.1}' data.single_view.prob=0.25) ;;
    nosv) extra=('data.train_pose_mix={id:0.4,ood:0.4,limb1:0.1,limb2:0.1}' data.single_view.prob=0) ;;
    id)   extra=(data.single_view.prob=0) ;;
    *) echo "unknown arm $arm" >&2; exit 2 ;;
  esac
  .venv/bin/python -m arteq.train "${COMMON[@]}" "${extra[@]}" hydra.run.dir="$OUT/$arm" > "$OUT/$arm.log" 2>&1
  cat "$OUT/$arm/metrics.md"
done
