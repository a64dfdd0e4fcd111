#!/usr/bin/env bash
# Bodies cut off by the sensor's frame (data.single_view.frame_px): controlled arms from the shipped scan model.
# Every arm starts from anny_scan's weights (experiments/pretrained/scan_gpu7_resume.ckpt, a fresh optimizer)
# and trains stage 2 for 500 steps (batch 8, lr 1e-4 cosine, seed 5, the training stream's epoch 30: clouds the
# shipped model never drew, gpu7's athletic pose mix, half single views, 500 points, any orientation, the
# all-ages body and shapes), then is tested on 128 clouds of every full-surface set and of the front, side,
# back, top and near view sets (the same clouds for every arm). Only the training single views differ:
#   sv50     cropped to the body as before (the control)
#   frame50  in a 640 x 480 frame centred on the pelvis (1-4 m: the near ones lose the head or the lower legs)
#   frame25  half of the single views in that frame (data.single_view.frame_prob=0.5), the others cropped
#   bash experiments/scan_model/frame_arms.sh [ARM ...]   (one thread each; outputs/frame_arms/<arm>/metrics.md)
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
INIT=${INIT:-experiments/pretrained/scan_gpu7_resume.ckpt}
OUT=${OUT:-outputs/frame_arms}
mkdir -p "$OUT"
COMMON=(+experiment=stage2 model=arteq_local body_model=anny_allages data.shape_prior=allages seed=5
        data.train_epoch_offset=30 data.augment=so3 data.eval_augment=so3 data.train_size=4000
        data.wide_poses=0.5 'data.train_pose_mix={id:0.4,ood:0.2,athletic:0.2,limb1:0.1,limb2:0.1}'
        data.single_view.prob=0.5 'data.view_splits=[front,side,back,top,near]' stage1.ckpt="$INIT"
        trainer.max_epochs=1 model.optimizer.lr=1e-4 data.val_size=32 data.test_size=128
        mean_pose_baseline=false trainer.enable_progress_bar=false)
ARMS=("$@"); [ ${#ARMS[@]} -gt 0 ] || ARMS=(sv50 frame50)
for arm in "${ARMS[@]}"; do
  case $arm in
    sv50) extra=() ;;
    frame50) extra=('data.single_view.frame_px=[640,480]') ;;
    frame25) extra=('data.single_view.frame_px=[640,480]' data.single_view.frame_prob=0.5) ;;
    *) echo "unknown arm $arm" >&2; exit 2 ;;
  esac
  .venv/bin/python -m arteq.train "${COMMON[@]}" "${extra[@]}" hydra.run.dir="$OUT/$arm" > "$OUT/$arm.log" 2>&1
  cat "$OUT/$arm/metrics.md"
done
