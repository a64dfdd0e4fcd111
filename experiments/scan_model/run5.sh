#!/usr/bin/env bash
# run5: a third cosine cycle for the scan-fitting model, with the share of single views and the pose mix the
# 300-step arms chose (view_mix.sh; experiments/single_view/README.md, experiments/scan_model/README.md).
# run4's finished weights (experiments/pretrained/scan_run4_resume.ckpt: run3 + 3000 steps), weights only (a
# fresh optimizer), 6 epochs (3000 steps) at lr 3e-4 cosine. data.train_epoch_offset=14: the training stream's
# epochs 14-19, clouds run3 (epochs 0-13) and run4 (0-5) never drew; data.seed stays 0, so the validation and
# test sets are theirs (comparable).
# Resumable like run.sh: run it again and it continues from outputs/scan_model/run5's newest checkpoint.
#   nohup bash experiments/scan_model/run5.sh > outputs/scan_model/run5.log 2>&1 &
# run6, a fourth cycle from run5's final weights at lr 1e-4 on the stream's epochs 20-25 (README, run6):
#   RUN=outputs/scan_model/run6 INIT=experiments/pretrained/scan_run5_resume.ckpt LR=1e-4 OFFSET=20 SEED=3 \
#     nohup bash experiments/scan_model/run5.sh > outputs/scan_model/run6.log 2>&1 &
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=${THREADS:-1} MKL_NUM_THREADS=${THREADS:-1} PYTHONUNBUFFERED=1
RUN=${RUN:-outputs/scan_model/run5}
INIT=${INIT:-experiments/pretrained/scan_run4_resume.ckpt}
ARGS=(+experiment=stage2 model=arteq_local body_model=anny_allages data.shape_prior=allages seed=${SEED:-2}
      data.train_epoch_offset=${OFFSET:-14}
      data.augment=so3 data.eval_augment=so3 data.train_size=4000 data.wide_poses=0.5
      "data.train_pose_mix=${MIX:-{id:0.4,ood:0.4,limb1:0.1,limb2:0.1}}" data.single_view.prob=${SV:-0.5}
      'data.view_splits=[front,side,back,top]' stage1.ckpt=$INIT model.optimizer.lr=${LR:-3e-4}
      trainer.max_epochs=6 mean_pose_baseline=false trainer.enable_progress_bar=false)
if [ -d "$RUN/checkpoints" ]; then
  exec .venv/bin/python -m arteq.train "${ARGS[@]}" resume="$RUN" "$@"
else
  exec .venv/bin/python -m arteq.train "${ARGS[@]}" hydra.run.dir="$RUN" "$@"
fi
