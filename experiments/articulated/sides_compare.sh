#!/usr/bin/env bash
# Controlled comparison of model.net.sides (section 3c of README.md): the part-local research model at stage-2
# step 3150 (experiments/pretrained/arteq_local_resume.ckpt as committed in d11fb00; get it with
# `git show d11fb00:experiments/pretrained/arteq_local_resume.ckpt > init3150.ckpt`), fine-tuned in stage 2 for
# 300 steps (batch 8, lr 1e-3 cosine, seed 0, 500 points, random orientations, widened ID poses) once with
# each side rule, then tested on 128 clouds of every test set. One thread per arm, the two arms side by side.
#   bash experiments/articulated/sides_compare.sh init3150.ckpt
set -euo pipefail
cd "$(dirname "$0")/../.."
INIT=${1:?usage: sides_compare.sh INIT_CKPT}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
mkdir -p outputs/sides
for arm in learned torso; do
  .venv/bin/python -m arteq.train +experiment=stage2 model=arteq_local seed=0 data.augment=so3 data.eval_augment=so3 \
    data.train_size=2400 data.wide_poses=0.5 trainer.max_epochs=1 mean_pose_baseline=false \
    trainer.enable_progress_bar=false stage1.ckpt="$INIT" model.optimizer.lr=1e-3 data.val_size=32 \
    data.test_size=128 model.net.sides=$arm hydra.run.dir=outputs/sides/$arm > outputs/sides/$arm.log 2>&1 &
done
wait
cat outputs/sides/learned/metrics.md outputs/sides/torso/metrics.md
