"""Helpers shared by the fitting tests (not a test module)."""

from __future__ import annotations

from pathlib import Path

import torch

from arteq.fit.api import Fitter


class CentreKeepingFitter(Fitter):
    """A ``Fitter`` that remembers the last prepared scan's centre (``self._centre``), for test subclasses
    whose ``_network`` stands in for the network with a known answer in the scan's frame."""

    def prepare(self, points, units="m", name="points"):
        item = super().prepare(points, units, name)
        self._centre = item["center"]
        return item


def write_tiny_checkpoint(path: Path, net: dict) -> Path:
    """An untrained, weights-only checkpoint of ``net`` (the ``tiny_net`` fixture: ArtEqNet keyword
    arguments) in the shipped format (network input: 500 points)."""
    import lightning

    from arteq.training.module import ArtEqModule

    torch.manual_seed(0)
    m = ArtEqModule(net=net, body_model={"name": "anny22"}, data={"num_points": 500})
    state = {"state_dict": m.state_dict(), "hyper_parameters": dict(m.hparams)}
    torch.save({**state, "pytorch-lightning_version": lightning.__version__}, path)
    return path


def posed(body, pose, betas, transl) -> dict:
    """``vertices``, ``joints``, ``global_rotmats`` (float64 numpy) of ``body`` in a pose (``[22, 3, 3]``
    local rotations), with betas and a translation."""
    with torch.no_grad():
        o = body(
            betas=torch.as_tensor(betas, dtype=torch.float32)[None],
            pose=torch.as_tensor(pose, dtype=torch.float32)[None],
            transl=torch.as_tensor(transl, dtype=torch.float32)[None],
        )
    return {k: getattr(o, k)[0].double().numpy() for k in ("vertices", "joints", "global_rotmats")}


def reading_of(vertices, pose, betas, transl) -> type:
    """A :class:`CentreKeepingFitter` whose "network" reads every draw of a scan as the body with
    ``vertices`` (its points labelled by their nearest vertex's part), ``pose``, ``betas`` and ``transl``
    (scan frame): a known answer for the steps after the network."""
    import numpy as np
    from scipy.spatial import cKDTree

    class Reading(CentreKeepingFitter):
        @torch.no_grad()
        def _network(self, clouds, turns=None, shifts=None, torso=None):
            c, k = self._centre, len(clouds)
            tree = cKDTree(vertices - c)
            lab = np.stack([self.vertex_parts[tree.query(p)[1]] for p in clouds])
            return {
                "part_probs": torch.as_tensor(np.eye(22)[lab] * 0.9 + 0.1 / 22, dtype=torch.float32),
                "local_rotmats": torch.as_tensor(pose, dtype=torch.float32)[None].expand(k, -1, -1, -1),
                "betas": torch.as_tensor(betas, dtype=torch.float32)[None].expand(k, -1),
                "transl": torch.as_tensor(transl - c, dtype=torch.float32)[None].expand(k, -1),
            }

    return Reading


def unit(v):
    """``v`` as a float64 unit vector."""
    import numpy as np

    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)
