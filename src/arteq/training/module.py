"""LightningModule around the ArtEq network: losses, both training stages, metrics per split."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import lightning as L
import torch

from arteq.body.factory import create_body
from arteq.config import to_plain
from arteq.geometry.pointops import fps_from_centroid
from arteq.io.runs import read_checkpoint
from arteq.models.placement import body_centroid_matrix, estimate_translation
from arteq.models.precision import full_precision, upcast
from arteq.models.registry import build_net
from arteq.results import ALL_TEST_SPLITS, TEST_SPLITS, VIEW_SPLITS, metric_values
from arteq.training.breakdown import SplitBreakdown, has_shape_meta
from arteq.training.losses import DEFAULT_WEIGHTS, arteq_losses
from arteq.training.metrics import BodyFitMetrics
from arteq.training.optim import DEFAULT_OPTIMIZER, DEFAULT_SCHEDULER, build_optimizer, build_scheduler


def batch_fps_idx(batch: Mapping[str, torch.Tensor]) -> torch.Tensor | None:
    """A batch's precomputed FPS indices (``data.fps_points``), or ``None`` when it has none or its points
    are no longer the float32 clouds they were computed from (a ``*-true`` half-precision trainer
    converts the batch: the network then samples the rounded points itself)."""
    fps_idx = batch.get("fps_idx")
    if fps_idx is None or batch["points"].dtype != torch.float32:
        return None
    return fps_idx


class ArtEqModule(L.LightningModule):
    """Trains and evaluates :class:`ArtEqNet`.

    Args:
        net: keyword arguments of :class:`ArtEqNet` (``num_betas`` is taken from ``body_model``).
        body_model: the body's config for :func:`arteq.body.create_body` (``name``, ``model_path``,
            ``num_betas``...). The body model is rebuilt from this at load time and is *not* stored in
            checkpoints (SMPL files are licensed and must not be redistributed inside them).
        stage: 1 pools part features with ground-truth labels (all modules trained); 2 pools with
            the predicted part probabilities (end to end).
        loss_weights: see :mod:`arteq.training.losses`.
        optimizer: a Hydra partial (``{"_target_": "torch.optim.Adam", "_partial_": True, "lr": ...}``) or
            the earlier ``{"name": "adam"|"adamw", "lr": ..., "weight_decay": ...}``
            (:mod:`arteq.training.optim`).
        scheduler: a Hydra partial with ``interval``, or ``{"name": "none"|"cosine"|"step", ...}``.
        markers: number of marker vertices weighted ``marker_weight`` in the vertex loss.
        data: the data configuration trained on; recorded in checkpoints (provenance, and so that a
            stage-2 run only picks up a stage-1 run trained on the same kind of data), not used here.
        body: the body model of ``body_model`` when the caller has built it already (it becomes this
            module's own: moved with it to its device); not a hyperparameter.

    After ``trainer.test``, :attr:`test_results` holds ``{split: {metric: value}}`` (see
    :mod:`arteq.results`), the values this module logged: the datamodule's ``test_splits``, then its
    single-view test sets (``view_splits``, :data:`arteq.results.VIEW_SPLITS`) when it has any; and
    :attr:`test_breakdown` ``{split: {grouping: {group: {count, metric: value}}}}``, the same metrics per age
    band and per build (:mod:`arteq.training.breakdown`) of the splits whose clouds record what body they
    are (drawn with ``data.shape_prior=allages``), empty for the others.
    """

    def __init__(
        self,
        net: Mapping[str, Any] | None = None,
        body_model: Mapping[str, Any] | None = None,
        stage: int = 2,
        loss_weights: Mapping[str, float] | None = None,
        optimizer: Mapping[str, Any] | None = None,
        scheduler: Mapping[str, Any] | None = None,
        markers: int = 64,
        marker_weight: float = 2.0,
        data: Mapping[str, Any] | None = None,
        body: torch.nn.Module | None = None,
    ):
        super().__init__()
        net = dict(to_plain(net) or {})
        body_model = {k: v for k, v in dict(to_plain(body_model) or {}).items() if k != "_target_"}
        if stage not in (1, 2):
            raise ValueError(f"stage must be 1 or 2, got {stage}")
        self.save_hyperparameters(
            {
                "net": net,
                "body_model": body_model,
                "stage": stage,
                "loss_weights": dict(to_plain(loss_weights) or DEFAULT_WEIGHTS),
                "optimizer": dict(to_plain(optimizer) or DEFAULT_OPTIMIZER),
                "scheduler": dict(to_plain(scheduler) or DEFAULT_SCHEDULER),
                "markers": markers,
                "marker_weight": marker_weight,
                "data": dict(to_plain(data) or {}),
            }
        )
        self.body = create_body(body if body is not None else body_model)
        for name, buf in list(self.body.named_buffers(recurse=False)):
            self.body.register_buffer(name, buf, persistent=False)  # rebuilt from file, never saved
        for p in self.body.parameters():
            p.requires_grad_(False)
        net.setdefault("num_betas", self.body.num_betas)
        self.net = build_net(net)

        centroids = body_centroid_matrix(self.body, self.net.num_parts)
        self.register_buffer("centroid_matrix", centroids, persistent=False)
        template = self.body.v_template.detach().double()
        vw = torch.ones(template.shape[0])
        if markers > 0:
            # stand-ins for the mocap-marker vertices the paper weights twice in the vertex loss (SMPL's
            # marker indices do not exist on other topologies): vertices spread by farthest point sampling
            vw[fps_from_centroid(template[None].cpu(), markers)[0]] = marker_weight
        self.register_buffer("vertex_weights", vw, persistent=False)

        self.val_metrics = BodyFitMetrics()
        self.test_metrics = torch.nn.ModuleList([BodyFitMetrics() for _ in TEST_SPLITS])
        # the single-view test sets' (data.view_splits); metric states are not saved in checkpoints
        self.view_metrics = torch.nn.ModuleDict({s: BodyFitMetrics() for s in VIEW_SPLITS})
        # per age band and build (test sets drawn with the all-ages prior); no state in checkpoints either
        self.breakdown_metrics = torch.nn.ModuleDict({s: SplitBreakdown() for s in ALL_TEST_SPLITS})
        self.test_results: dict[str, dict[str, Any]] = {}
        self.test_breakdown: dict[str, dict[str, Any]] = {}

    # ------------------------------------------------------------------ inference
    def forward(
        self, points: torch.Tensor, gt_labels: torch.Tensor | None = None, fps_idx: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        """Full prediction for a batch of clouds ``[B, N, 3]`` (metres, any placement).

        ``fps_idx``: the backbone's FPS order precomputed by the data workers (a batch's ``fps_idx``, see
        ``data.fps_points``); the same indices the network would compute, so the outputs are the same.
        Ignored by networks that do not take it (the PointNet++ baseline).

        Returns the network outputs plus ``vertices [B,V,3]``, ``joints [B,22,3]`` and ``transl [B,3]``
        of the fitted body, in the frame of ``points``.
        """
        if fps_idx is not None and getattr(self.net, "accepts_fps_idx", False):
            pred = self.net(points, gt_labels=gt_labels, fps_idx=fps_idx)
        else:
            pred = self.net(points, gt_labels=gt_labels)
        with full_precision(points):  # the body model (LBS) and placement in float32 at least
            body = self.body(betas=upcast(pred["betas"]), pose=upcast(pred["local_rotmats"]))
            transl = estimate_translation(body.vertices, self.centroid_matrix, points, pred["pool_weights"])
            pred["vertices"] = body.vertices + transl[:, None]
            pred["joints"] = body.joints + transl[:, None]
        pred["transl"] = transl
        return pred

    def ground_truth(self, batch: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Ground-truth mesh and joints (in the batch's centred frame) from its body parameters."""
        with torch.no_grad(), full_precision(batch["points"]):
            body = self.body(betas=batch["betas"], pose=batch["pose"], transl=batch["transl"])
        return {**batch, "vertices": body.vertices, "joints": body.joints}

    # ------------------------------------------------------------------ steps
    def _step(self, batch: Mapping[str, torch.Tensor], use_gt_parts: bool):
        gt = self.ground_truth(batch)
        pred = self(
            batch["points"], gt_labels=batch["labels"] if use_gt_parts else None, fps_idx=batch_fps_idx(batch)
        )
        with full_precision(batch["points"]):  # losses in float32 at least, also under mixed precision
            pred32 = {k: upcast(v) for k, v in pred.items()}
            losses = arteq_losses(pred32, gt, self.hparams.loss_weights, self.vertex_weights)
        return pred, gt, losses

    def training_step(self, batch, batch_idx):
        _, _, losses = self._step(batch, use_gt_parts=self.hparams.stage == 1)
        bs = batch["points"].shape[0]
        terms = {f"train/{k}": v.detach() for k, v in losses.items() if k != "loss"}
        self.log_dict(terms, batch_size=bs)
        self.log("train/loss", losses["loss"].detach(), prog_bar=True, batch_size=bs)
        return losses["loss"]

    def _update(self, metric: BodyFitMetrics, pred, gt) -> None:
        metric.update(
            pred["vertices"],
            gt["vertices"],
            pred["joints"],
            gt["joints"],
            pred["global_rotmats"],
            gt["global_rotmats"],
            pred["seg_logits"].argmax(-1),
            gt["labels"],
        )

    def validation_step(self, batch, batch_idx):
        # Evaluation always runs the real pipeline: parts predicted, not given.
        pred, gt, losses = self._step(batch, use_gt_parts=False)
        self.log("val/loss", losses["loss"], batch_size=batch["points"].shape[0], sync_dist=True)
        self._update(self.val_metrics, pred, gt)

    def on_validation_epoch_end(self):
        self._log_metrics("val", self.val_metrics, prog_bar=True)

    def _test_split_names(self) -> tuple[str, ...]:
        """Names of the test loaders being run, in order: the datamodule's ``test_loader_splits``
        (its ``test_splits``, then its ``view_splits``; a datamodule without it: its ``test_splits``, else
        :data:`arteq.results.TEST_SPLITS`), cut to the number of loaders."""
        loaders = self.trainer.test_dataloaders if self._trainer is not None else None
        n_run = len(loaders) if isinstance(loaders, list | tuple) else 1
        dm = getattr(self._trainer, "datamodule", None) if self._trainer is not None else None
        names = tuple(getattr(dm, "test_loader_splits", None) or getattr(dm, "test_splits", TEST_SPLITS))
        return names[:n_run] if len(names) >= n_run else TEST_SPLITS[:n_run]

    def _test_metric(self, split: str) -> BodyFitMetrics:
        """The metric object of a test split (:data:`~arteq.results.TEST_SPLITS` or ``VIEW_SPLITS``)."""
        if split in self.view_metrics:
            return self.view_metrics[split]
        return self.test_metrics[TEST_SPLITS.index(split)]

    def test_step(self, batch, batch_idx, dataloader_idx: int = 0):
        pred, gt, _ = self._step(batch, use_gt_parts=False)
        split = self._test_split_names()[dataloader_idx]
        self._update(self._test_metric(split), pred, gt)
        if has_shape_meta(batch) and split in self.breakdown_metrics:
            with full_precision(batch["points"]):
                pred32 = {k: upcast(v) for k, v in pred.items()}
                gt32 = {k: upcast(v) if torch.is_tensor(v) else v for k, v in gt.items()}
                self.breakdown_metrics[split].update(gt32, self.body, pred32, gt32)

    def on_test_epoch_end(self):
        # Every rank computes every split that was run (even one whose shard of the set was empty):
        # compute() gathers the metric states of all ranks, so all of them must take part.
        self.test_results = {}
        self.test_breakdown = {}
        for split in self._test_split_names():
            self.test_results[split] = self._log_metrics(split, self._test_metric(split))
            if split in self.breakdown_metrics:
                breakdown = self._breakdown_results(self.breakdown_metrics[split])
                if breakdown is not None:
                    self.test_breakdown[split] = breakdown

    def _breakdown_results(self, metric: SplitBreakdown) -> dict[str, Any] | None:
        """A split's breakdown (None when no rank saw a cloud that records its body: a normal-prior set)."""
        seen = torch.tensor(float(metric.update_called), device=self.device)
        if self._trainer is not None and self.trainer.world_size > 1:  # every rank takes the same branch
            seen = self.trainer.strategy.reduce(seen, reduce_op="max")
        if not bool(seen > 0):
            return None
        results = metric.compute()
        metric.reset()
        return results

    def _log_metrics(self, split: str, metric: BodyFitMetrics, prog_bar: bool = False) -> dict[str, Any]:
        """Log a split's metrics and return them as results (the logged float32 values)."""
        # compute() sums the metric states over all ranks (torchmetrics), so every rank holds the same
        # values; sync_dist with "max" only tells Lightning so, and leaves the values bit for bit as they are.
        values = {k: v.float() for k, v in metric.compute().items()}
        results = metric_values(values)
        per_part = values.pop("rot_err_deg_per_part")
        for k, v in values.items():
            self.log(
                f"{split}/{k}", v, prog_bar=prog_bar and k in ("v2v_cm", "part_acc"),
                sync_dist=True, reduce_fx="max",
            )  # fmt: skip
        from arteq.body.skeleton import JOINT_NAMES

        for name, v in zip(JOINT_NAMES, per_part):
            self.log(f"{split}_rot_per_part/{name}", v, sync_dist=True, reduce_fx="max")
        metric.reset()
        return results

    # ------------------------------------------------------------------ optimisation
    def configure_optimizers(self):
        """``model.optimizer`` / ``model.scheduler`` (Hydra partials, or the earlier ``{name: ...}`` form):
        :mod:`arteq.training.optim`."""
        optimizer = build_optimizer(dict(self.hparams.optimizer), self.net.parameters())
        # the number of steps only when the schedule asks for it (Lightning sets up the training data for it)
        sched = build_scheduler(
            dict(self.hparams.scheduler), optimizer, lambda: self.trainer.estimated_stepping_batches
        )
        return optimizer if sched is None else {"optimizer": optimizer, "lr_scheduler": sched}

    # ------------------------------------------------------------------ stage 2 initialisation
    def load_net_weights(self, ckpt_path: str, reinit_mismatched: bool = False) -> list[str]:
        """Initialise the network from another checkpoint (stage 1 -> stage 2); optimizer starts fresh.

        ``reinit_mismatched``: tensors whose shape differs from the checkpoint's (the shape head's output
        when the checkpoint was trained on a body with another number of betas) keep this network's fresh
        initialisation instead of failing. Returns their names (empty when every tensor was loaded)."""
        state = read_checkpoint(ckpt_path)
        if "state_dict" not in state:
            raise ValueError(f"{ckpt_path}: not a Lightning checkpoint (no 'state_dict')")
        net_state = {k[4:]: v for k, v in state["state_dict"].items() if k.startswith("net.")}
        own = self.net.state_dict()
        mismatched = [k for k, v in net_state.items() if k in own and own[k].shape != v.shape]
        if mismatched and not reinit_mismatched:
            shapes = ", ".join(
                f"{k} {list(net_state[k].shape)} vs {list(own[k].shape)}" for k in mismatched[:3]
            )
            raise ValueError(
                f"{ckpt_path}: tensor shapes differ from this config's ({shapes}); stage 1 and stage 2 must "
                "use the same model and body (stage1.reinit_mismatched=true re-initialises those tensors, "
                "e.g. the shape head's output for a body with another number of betas)"
            )
        for k in mismatched:
            net_state[k] = own[k]
        missing, unexpected = self.net.load_state_dict(net_state, strict=False)
        if missing or unexpected:
            raise ValueError(
                f"{ckpt_path}: network does not match this config (missing {missing[:5]}, "
                f"unexpected {unexpected[:5]}); stage 1 and stage 2 must use the same model config"
            )
        return mismatched
