#!/usr/bin/env bash
# run4: a second cosine cycle for the scan-fitting model. run3's finished weights (shipped as anny_scan,
# experiments/pretrained/scan_local_resume.ckpt at step 7000) trained 6 more epochs (3000 steps) of the same
# data and mix at lr 3e-4 (cosine to 5 %), weights only (a fresh optimizer). Asks whether the in-distribution
# precision that separates anny_scan from anny22 (7.2 against 4.5 cm V2V, network alone) still moves.
# seed=1 changes the run's own random state, not its clouds: data.seed stays 0, so the training stream is
# run3's first 6 epochs again and the validation set is run3's (comparable).
# Resumable like run.sh: run it again and it continues from outputs/scan_model/run4's newest checkpoint.
#   nohup bash experiments/scan_model/run4.sh > outputs/scan_model/run4.log 2>&1 &
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=${THREADS:-1} MKL_NUM_THREADS=${THREADS:-1} PYTHONUNBUFFERED=1
RUN=${RUN:-outputs/scan_model/run4}
INIT=${INIT:-experiments/pretrained/scan_local_resume.ckpt}
ARGS=(+experiment=stage2 model=arteq_local body_model=anny_allages data.shape_prior=allages seed=1
      data.augment=so3 data.eval_augment=so3 data.train_size=4000 data.wide_poses=0.5
      'data.train_pose_mix={id:0.4,ood:0.4,limb1:0.1,limb2:0.1}' data.single_view.prob=0.25
      'data.view_splits=[front,side,back,top]' stage1.ckpt=$INIT model.optimizer.lr=3e-4
      trainer.max_epochs=6 mean_pose_baseline=false trainer.enable_progress_bar=false)
if [ -d "$RUN/checkpoints" ]; then
  exec .venv/bin/python -m arteq.train "${ARGS[@]}" resume="$RUN" "$@"
else
  exec .venv/bin/python -m arteq.train "${ARGS[@]}" hydra.run.dir="$RUN" "$@"
fi
