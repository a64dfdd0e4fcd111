#!/usr/bin/env bash
# The scan-fitting model (issue 19, item 2): the part-local network of the articulated-equivariance work
# (model=arteq_local, left / right from the torso frame) on the all-ages body (children to elderly, extreme
# builds: body_model=anny_allages, data.shape_prior=allages), trained on the broadest pose mix the project
# samples (everyday motions, half of them widened; the hard OOD sampler: joint-limit poses and extreme
# templates; everyday poses with one / two OOD limbs), any orientation, a quarter of the clouds single-view
# depth scans, 500 points. Stage 2 for 7000 steps (14 epochs of 500), lr 1e-3 cosine, one thread,
# initialised from the finished research model (the shipped anny22_local weights: research_run.sh at
# stage-2 step 6500; the shape head's output, 10 betas there and 16 here, starts fresh:
# stage1.reinit_mismatched). run3: the earlier run2 started from the research model at stage-2 step 1250
# and did not learn (README.md); 300-step arms from the finished research model did (arms.sh).
# Resumable: run it again and it continues from its newest checkpoint (a step checkpoint every 25 steps).
#   mkdir -p outputs/scan_model && nohup bash experiments/scan_model/run.sh > outputs/scan_model/run3.log 2>&1 &
# Held out from training: the test sets (their own seeds), the user-scan suite's acrobatic templates
# (experiments/fitting/user_scans.py), and the single-view test sets.
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=${THREADS:-1} MKL_NUM_THREADS=${THREADS:-1} PYTHONUNBUFFERED=1  # THREADS=2 on idle cores
RUN=${RUN:-outputs/scan_model/run3}
ARGS=(+experiment=stage2 model=arteq_local body_model=anny_allages data.shape_prior=allages seed=0
      data.augment=so3 data.eval_augment=so3 data.train_size=4000 data.wide_poses=0.5
      'data.train_pose_mix={id:0.4,ood:0.4,limb1:0.1,limb2:0.1}' data.single_view.prob=0.25
      'data.view_splits=[front,side,back,top]' stage1.ckpt=src/arteq/pretrained/anny22_local.ckpt model.optimizer.lr=1e-3
      stage1.reinit_mismatched=true trainer.max_epochs=14
      mean_pose_baseline=false trainer.enable_progress_bar=false)
if [ -d "$RUN/checkpoints" ]; then
  exec .venv/bin/python -m arteq.train "${ARGS[@]}" resume="$RUN" "$@"
else
  exec .venv/bin/python -m arteq.train "${ARGS[@]}" hydra.run.dir="$RUN" "$@"
fi
