#!/usr/bin/env bash
# Holes in the training clouds (data.holes): does a network that saw scans with holes fit them better?
# Controlled arms from the shipped scan model's weights (experiments/pretrained/scan_gpu7_resume.ckpt, weights
# only, a fresh optimizer): 400 stage-2 steps each (batch 8, lr 3e-4 cosine, seed 0, the stream's epoch 40
# that no run drew, 500 points, any orientation, the all-ages body and shapes, half single views, the athletic
# pose mix: gpu7's recipe), then tested on 128 clouds of every full-surface and view test set (the same clouds
# for every arm; the test sets have no holes). Only data.holes differs:
#   base   no holes (gpu7's recipe continued: the arms' baseline)
#   holes  half the full-surface clouds with 1-8 holes of 3-12 cm radius (data.holes defaults)
#   bash experiments/scan_model/holes_mix.sh ARM     (one thread; run the arms side by side)
# The fits: experiments/fitting/scan_defects.py --ckpt outputs/holes_mix/ARM/checkpoints/last.ckpt
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
INIT=${INIT:-experiments/pretrained/scan_gpu7_resume.ckpt}
OUT=${OUT:-outputs/holes_mix}
mkdir -p "$OUT"
COMMON=(+experiment=stage2 model=arteq_local body_model=anny_allages data.shape_prior=allages seed=0
        data.train_epoch_offset=40 data.augment=so3 data.eval_augment=so3 data.train_size=3200
        data.wide_poses=0.5 data.single_view.prob=0.5 'data.view_splits=[front,side,back,top]'
        'data.train_pose_mix={id:0.4,ood:0.2,athletic:0.2,limb1:0.1,limb2:0.1}'
        stage1.ckpt="$INIT" trainer.max_epochs=1 model.optimizer.lr=3e-4 data.val_size=32 data.test_size=128
        mean_pose_baseline=false trainer.enable_progress_bar=false)
arm=$1
case $arm in
  base) extra=(data.holes.prob=0.0) ;;
  holes) extra=(data.holes.prob=0.5) ;;
  *) echo "unknown arm $arm" >&2; exit 2 ;;
esac
.venv/bin/python -m arteq.train "${COMMON[@]}" "${extra[@]}" hydra.run.dir="$OUT/$arm" > "$OUT/$arm.log" 2>&1
cat "$OUT/$arm/metrics.md"
