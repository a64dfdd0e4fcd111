#!/usr/bin/env bash
# The research model of the articulated-equivariance work (issue 18): the part-local network
# (model=arteq_local: metric radii, neighbour means, 250 deep centres, invariant parent feature, part-geometry
# tokens, group cross-entropy), ID-only training poses (half of them widened), any orientation, 500 points;
# stage 1 for 1000 steps, then stage 2 for 6500 (13 epochs of 500; 8 until stage-2 step ~850 of the run, extended for >= 5 CPU-hours), one thread;
# left / right from the torso frame (model.net.sides=torso, now in model=arteq_local) from stage-2 step 3400 on (before: the
# segmenter's own sides; no new weights, the switch is recorded in the checkpoints). Resumable: run it again and it
# continues from its newest checkpoint (a step checkpoint every 25 steps).
#   nohup bash experiments/articulated/research_run.sh > outputs/research/local3.log 2>&1 &
set -euo pipefail
cd "$(dirname "$0")/../.."
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
RUN=${RUN:-outputs/research/local3}
ARGS=(+experiment=stage2 model=arteq_local seed=0 data.augment=so3 data.eval_augment=so3 data.train_size=4000
      data.wide_poses=0.5 stage1.epochs=2 trainer.max_epochs=13 mean_pose_baseline=false
      trainer.enable_progress_bar=false)
if [ -d "$RUN/checkpoints" ] || [ -d "$RUN/stage1/checkpoints" ]; then
  exec .venv/bin/python -m arteq.train "${ARGS[@]}" resume="$RUN"
else
  exec .venv/bin/python -m arteq.train "${ARGS[@]}" hydra.run.dir="$RUN"
fi
