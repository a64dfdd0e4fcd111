"""The training step with the instance norm and kinematics of 2026-12-06 against their forms before, in one
process, interleaved (old, new, old, new ...), so that the ratio holds while the machine's speed drifts.

    OMP_NUM_THREADS=2 python benchmarks/bench_kernel_pairs.py [--pairs 12] [--points 500] [--override ...]

Default overrides: the scan model's training config (``model=arteq_local body_model=anny_allages
data.shape_prior=allages``). The step is that of ``bench_train_step.py`` (forward, losses, backward, Adam with
learning rate 0, so every step sees the same weights and batch). "Before" is the norm as ``torch.var_mean``
over the strided dims (1, 2), and forward kinematics one joint at a time; each is swapped in where the code
looks it up. Prints both losses (the same to float rounding) and the median ratio new / old over the pairs.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

SCAN_MODEL = ["model=arteq_local", "body_model=anny_allages", "data.shape_prior=allages"]


def norm_before(x: torch.Tensor, eps: float = 1e-5) -> torch.Tensor:
    with torch.autocast(x.device.type, enabled=False):
        xf = x.float() if x.dtype in (torch.float16, torch.bfloat16) else x
        var, mean = torch.var_mean(xf, dim=(1, 2), keepdim=True, unbiased=False)
        return (xf - mean) * torch.rsqrt(var + eps)


def local_to_global_before(local: torch.Tensor, parents: tuple[int, ...] | None = None) -> torch.Tensor:
    from arteq.body.skeleton import PARENTS

    parents = PARENTS if parents is None else parents
    out = [local[..., 0, :, :]]
    for k in range(1, len(parents)):
        out.append(out[parents[k]] @ local[..., k, :, :])
    return torch.stack(out, dim=-3)


def skin_before(v_shaped, rest_joints, pose, lbs_weights, parents=None, posedirs=None, transl=None):
    from arteq.body.lbs import pose_features
    from arteq.body.skeleton import PARENTS

    parents = PARENTS if parents is None else parents
    b, v, _ = v_shaped.shape
    if posedirs is not None:
        feats = pose_features(pose)
        v_shaped = v_shaped + (feats @ posedirs[: feats.shape[1]]).view(b, v, 3)
    global_rot = local_to_global_before(pose, tuple(parents))
    posed = [rest_joints[:, 0]]
    for k in range(1, len(parents)):
        p = parents[k]
        offset = rest_joints[:, k] - rest_joints[:, p]
        posed.append(posed[p] + (global_rot[:, p] @ offset.unsqueeze(-1)).squeeze(-1))
    joints = torch.stack(posed, dim=1)
    trans = joints - (global_rot @ rest_joints.unsqueeze(-1)).squeeze(-1)
    rot_v = torch.einsum("vk,bkij->bvij", lbs_weights, global_rot)
    trans_v = torch.einsum("vk,bki->bvi", lbs_weights, trans)
    verts = (rot_v @ v_shaped.unsqueeze(-1)).squeeze(-1) + trans_v
    if transl is not None:
        verts, joints = verts + transl[:, None], joints + transl[:, None]
    return verts, joints, global_rot


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=12)
    ap.add_argument("--points", type=int, default=500)
    ap.add_argument("--override", nargs="*", default=SCAN_MODEL, help="Hydra overrides of the config")
    a = ap.parse_args()

    import bench_train_step

    import arteq.body.model as body_model
    import arteq.body.skeleton as skeleton
    import arteq.equivariant.layers as layers
    import arteq.training.floor as floor
    from arteq.runtime import tune_cpu_allocator

    tune_cpu_allocator()
    lbs = sys.modules["arteq.body.lbs"]  # (arteq.body.lbs is also the name of a function)
    new = (layers.instance_norm, body_model.skin, skeleton.local_to_global)
    old = (norm_before, skin_before, local_to_global_before)

    def use(fns) -> None:
        layers.instance_norm, body_model.skin, skeleton.local_to_global = fns
        lbs.local_to_global = floor.local_to_global = fns[2]

    module, batch = bench_train_step.build(a.points, a.override)
    opt = torch.optim.Adam(module.net.parameters(), lr=0.0)

    def step() -> tuple[float, float]:
        t = time.perf_counter()
        loss = module._step(batch, use_gt_parts=False)[2]["loss"]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        return time.perf_counter() - t, float(loss)

    for fns in (old, new, old, new):  # warm-up
        use(fns)
        step()
    t_old, t_new = [], []
    for _ in range(a.pairs):
        use(old)
        t, loss_old = step()
        t_old.append(t)
        use(new)
        t, loss_new = step()
        t_new.append(t)
    use(new)
    ratios = [n / o for n, o in zip(t_new, t_old)]
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {a.points} points, "
          f"batch {batch['points'].shape[0]}, overrides {' '.join(a.override)}")  # fmt: skip
    print(f"loss before {loss_old:.6f}, now {loss_new:.6f}")
    spread = f"{min(ratios):.3f}-{max(ratios):.3f}"
    print(f"before {statistics.median(t_old):.3f} s/step, now {statistics.median(t_new):.3f}; "
          f"ratio now/before median {statistics.median(ratios):.3f} ({spread}), {a.pairs} pairs")  # fmt: skip


if __name__ == "__main__":
    main()
