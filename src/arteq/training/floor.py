"""The mean-pose floor: a predictor every trained network must clearly beat (``mean_pose_baseline``).

It predicts the training set's mean pose and the mean shape for every cloud, placed the way ArtEq
places bodies, and is scored with the training metrics. It needs the run's data and body only: no
network, no LightningModule.
"""

from __future__ import annotations

import roma
import torch
import torch.nn.functional as F
from omegaconf import DictConfig
from torch import nn

from arteq.body.skeleton import NUM_JOINTS, local_to_global
from arteq.models.placement import body_centroid_matrix, estimate_translation
from arteq.training.build import build_datamodule
from arteq.training.metrics import BodyFitMetrics


@torch.no_grad()
def evaluate_mean_pose(
    cfg: DictConfig, train_samples: int = 256, body: nn.Module | None = None
) -> dict[str, dict[str, float]]:
    """The floor's ``{split: {metric: value}}`` on the configured test sets (no ``part_acc``: it does
    not segment; no per-part errors).

    Mean local rotation per joint = SO(3) projection of the average training rotation matrix (training
    poses before any rotation augmentation); betas = 0 (the shape space's mean). Translation uses the
    ground-truth part labels (generous). ``body``: the run's body model (built from ``cfg.body_model``
    when not given).
    """
    dm = build_datamodule(cfg, body)
    dm.fps_points = 0  # no network here: batches without precomputed FPS indices
    body = dm.body
    # the training poses without rotation augmentation: with so3 augmentation the mean root
    # orientation would be meaningless, and this floor is about the pose distribution itself
    train_ds = dm.make_dataset("train")
    n = min(train_samples, len(train_ds))
    poses = torch.stack([train_ds.source_sample(i)["pose"] for i in range(n)])
    poses = roma.rotvec_to_rotmat(poses.double())
    mean_local = roma.special_procrustes(poses.mean(0)).float()  # [22, 3, 3]
    centroids = body_centroid_matrix(body, NUM_JOINTS)
    dm.setup("test")
    out: dict[str, dict[str, float]] = {}
    for split, loader in zip(dm.test_splits, dm.test_dataloader()):
        # this process's own evaluation (run on rank 0 only in a distributed run): no cross-rank sync
        metric = BodyFitMetrics(sync_on_compute=False)
        for batch in loader:
            b = batch["points"].shape[0]
            gt = body(betas=batch["betas"], pose=batch["pose"], transl=batch["transl"])
            pose = mean_local.expand(b, -1, -1, -1)
            pred = body(betas=torch.zeros(b, body.num_betas), pose=pose)
            onehot = F.one_hot(batch["labels"], NUM_JOINTS).float()
            t = estimate_translation(pred.vertices, centroids, batch["points"], onehot)
            metric.update(
                pred.vertices + t[:, None], gt.vertices, pred.joints + t[:, None], gt.joints,
                local_to_global(pose), batch["global_rotmats"],
                torch.full_like(batch["labels"], -1), batch["labels"],
            )  # fmt: skip
        values = metric.compute()
        values.pop("rot_err_deg_per_part")
        values.pop("part_acc")  # no segmentation: not applicable
        out[split] = {k: float(v) for k, v in values.items()}
    return out
