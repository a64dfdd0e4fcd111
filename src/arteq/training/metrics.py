"""Body-fitting metrics as a torchmetrics Metric (accumulates over batches and devices).

Units: errors in centimetres and degrees, accuracy in percent. MPJPE is over the 22 body joints of
the skeleton (pelvis .. wrists; SMPL's hand joints are folded into the wrists), with no alignment.
V2V is the mean distance between corresponding vertices, over all vertices, with no alignment.
"""

from __future__ import annotations

import torch
from torchmetrics import Metric

from arteq.body.skeleton import NUM_JOINTS
from arteq.geometry.rotations import geodesic_deg


class BodyFitMetrics(Metric):
    """Part accuracy (%), V2V (cm), MPJPE over 22 joints (cm), global rotation error per part (deg)."""

    full_state_update = False
    higher_is_better = False

    def __init__(self, num_parts: int = NUM_JOINTS, **kwargs):
        super().__init__(**kwargs)
        self.num_parts = num_parts
        self.add_state("v2v_sum", torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("mpjpe_sum", torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("rot_sum", torch.zeros(num_parts, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("bodies", torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")
        self.add_state("correct", torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")
        self.add_state("points", torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")

    def update(
        self,
        pred_vertices: torch.Tensor,
        gt_vertices: torch.Tensor,
        pred_joints: torch.Tensor,
        gt_joints: torch.Tensor,
        pred_rotmats: torch.Tensor,
        gt_rotmats: torch.Tensor,
        pred_labels: torch.Tensor,
        gt_labels: torch.Tensor,
    ) -> None:
        """Shapes: vertices ``[B,V,3]``, joints ``[B,22,3]`` (metres), rotmats ``[B,22,3,3]`` (global),
        labels ``[B,N]``."""
        self.v2v_sum += (pred_vertices - gt_vertices).norm(dim=-1).mean(dim=-1).double().sum() * 100
        self.mpjpe_sum += (pred_joints - gt_joints).norm(dim=-1).mean(dim=-1).double().sum() * 100
        self.rot_sum += geodesic_deg(pred_rotmats.double(), gt_rotmats.double()).sum(dim=0)
        self.bodies += pred_vertices.shape[0]
        self.correct += (pred_labels == gt_labels).sum()
        self.points += gt_labels.numel()

    def compute(self) -> dict[str, torch.Tensor]:
        n = self.bodies.clamp_min(1)
        per_part = self.rot_sum / n
        return {
            "part_acc": 100.0 * self.correct.double() / self.points.clamp_min(1),
            "v2v_cm": self.v2v_sum / n,
            "mpjpe_cm": self.mpjpe_sum / n,
            "rot_err_deg": per_part.mean(),
            "rot_err_deg_per_part": per_part,
        }
