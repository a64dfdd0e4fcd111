#!/usr/bin/env bash
# Does an athlete's joint range in training fix the acrobatic fits? (issue 19: acrobatic poses). Controlled
# arms from run5's final weights (experiments/pretrained/scan_run5_resume.ckpt, weights only, a fresh
# optimizer): 600 stage-2 steps each (batch 8, lr 3e-4 cosine, seed 0, the stream's epoch 26 that no run
# drew, 500 points, any orientation, the all-ages body and shapes, half single views: run5's recipe), then
# tested on 128 clouds of every full-surface and view test set (the same clouds for every arm). Only the
# pose mix differs:
#   base      run5's {id:0.4, ood:0.4, limb1:0.1, limb2:0.1}
#   athletic  half the ood share from the athletic sampler (poses.ATHLETIC_LIMITS_DEG: splits, back bends,
#             arms overhead): {id:0.4, ood:0.2, athletic:0.2, limb1:0.1, limb2:0.1}
#   bash experiments/scan_model/athletic_mix.sh ARM     (one thread; run the arms side by side)
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
INIT=${INIT:-experiments/pretrained/scan_run5_resume.ckpt}
OUT=${OUT:-outputs/athletic_mix}
mkdir -p "$OUT"
COMMON=(+experiment=stage2 model=arteq_local body_model=anny_allages data.shape_prior=allages seed=0
        data.train_epoch_offset=26 data.augment=so3 data.eval_augment=so3 data.train_size=4800
        data.wide_poses=0.5 data.single_view.prob=0.5 'data.view_splits=[front,side,back,top]'
        stage1.ckpt="$INIT" trainer.max_epochs=1 model.optimizer.lr=3e-4 data.val_size=32 data.test_size=128
        mean_pose_baseline=false trainer.enable_progress_bar=false)
arm=$1
case $arm in
  base) mix='{id:0.4,ood:0.4,limb1:0.1,limb2:0.1}' ;;
  athletic) mix='{id:0.4,ood:0.2,athletic:0.2,limb1:0.1,limb2:0.1}' ;;
  *) echo "unknown arm $arm" >&2; exit 2 ;;
esac
.venv/bin/python -m arteq.train "${COMMON[@]}" "data.train_pose_mix=$mix" hydra.run.dir="$OUT/$arm" \
  > "$OUT/$arm.log" 2>&1
cat "$OUT/$arm/metrics.md"
