"""Evaluate the optimisation fitter on test_id / test_ood with the training metrics.

``python -m arteq.fitting.evaluate --out experiments/fitting/opt [--samples 16] [--num-points 1000]``
fits from the standard start (rest pose, 24 root orientations tried, centroid translation);
``--refine RUN_DIR`` starts from that ArtEq run's prediction instead (ArtEq + refinement) and uses the
run's data configuration. Writes ``metrics.json`` / ``metrics.md`` in the format of
:func:`arteq.eval.write_metrics` (read by ``python -m arteq.report``), with ``method`` and ``fit``
(iterations, seconds per sample) added. Part accuracy: each point takes the part label of its nearest
fitted vertex.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from typing import Any

import torch

from arteq.fitting.fit import fit_body
from arteq.geometry.pointops import knn
from arteq.training.metrics import BodyFitMetrics

log = logging.getLogger("arteq.fitting")
SPLITS = ("test_id", "test_ood")


def find_checkpoint(run_dir: Path) -> Path:
    """The best checkpoint of a run (``checkpoints/epoch*.ckpt``), else ``checkpoints/last.ckpt``."""
    ckpts = sorted((run_dir / "checkpoints").glob("epoch*.ckpt"))
    if ckpts:
        return ckpts[-1]
    last = run_dir / "checkpoints" / "last.ckpt"
    if last.is_file():
        return last
    raise FileNotFoundError(f"{run_dir}: no checkpoints/epoch*.ckpt or checkpoints/last.ckpt")


def load_run_data_config(run_dir: Path) -> dict[str, Any]:
    """``data`` and ``body_model`` sections of a run's ``.hydra/config.yaml``."""
    from omegaconf import OmegaConf

    path = run_dir / ".hydra" / "config.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not found (is {run_dir} a training run folder?)")
    cfg = OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    return {"data": dict(cfg.get("data") or {}), "body_model": dict(cfg.get("body_model") or {})}


def evaluate_fitter(
    datamodule,
    body: torch.nn.Module,
    fit_kwargs: dict[str, Any],
    module=None,
    max_samples: int | None = None,
) -> dict[str, Any]:
    """Fit every test cloud (batches of the datamodule) and return metrics per split plus timing.

    ``module``: an :class:`arteq.training.module.ArtEqModule` whose prediction initialises the fit
    (refinement); None for the standard start.
    """
    datamodule.setup("test")
    out: dict[str, Any] = {"metrics": {}, "fit": {}}
    for split, loader in zip(SPLITS, datamodule.test_dataloader()):
        metric = BodyFitMetrics()
        seconds, iters, n = 0.0, [], 0
        for batch in loader:
            if max_samples is not None and n >= max_samples:
                break
            if max_samples is not None:
                batch = {k: v[: max_samples - n] for k, v in batch.items()}
            pts = batch["points"]
            with torch.no_grad():
                gt = body(betas=batch["betas"], pose=batch["pose"], transl=batch["transl"])
            t0 = time.time()
            init = None
            if module is not None:
                with torch.no_grad():
                    pred = module(pts)
                init = {"pose": pred["local_rotmats"], "betas": pred["betas"], "transl": pred["transl"]}
            res = fit_body(body, pts, init=init, **fit_kwargs)
            seconds += time.time() - t0
            iters.append(res.iterations)
            _, idx = knn(pts, res.vertices, 1)
            labels = body.part_labels[idx[..., 0]]
            metric.update(
                res.vertices, gt.vertices, res.joints, gt.joints, res.global_rotmats, gt.global_rotmats,
                labels, batch["labels"],
            )  # fmt: skip
            n += pts.shape[0]
            log.info("%s: %d samples fitted (%.1f s)", split, n, seconds)
        if n == 0:
            raise ValueError(f"{split}: the test set is empty")
        values = metric.compute()
        per_part = values.pop("rot_err_deg_per_part")
        from arteq.body.skeleton import JOINT_NAMES

        res_split = {k: float(v) for k, v in values.items()}
        res_split["rot_err_deg_per_part"] = {j: float(v) for j, v in zip(JOINT_NAMES, per_part)}
        out["metrics"][split] = res_split
        out["fit"][split] = {
            "samples": n,
            "mean_iterations": sum(iters) / len(iters),
            "seconds_per_sample": seconds / n,
        }
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(
        prog="python -m arteq.fitting.evaluate", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("--out", required=True, help="output folder (metrics.json / metrics.md)")
    ap.add_argument(
        "--refine", default=None, metavar="RUN_DIR", help="start from this ArtEq run's prediction"
    )
    ap.add_argument("--data-from", default=None, metavar="RUN_DIR", help="use this run's data config")
    ap.add_argument("--samples", type=int, default=16, help="test clouds fitted per split")
    ap.add_argument("--num-points", type=int, default=1000, help="points per cloud (without --refine)")
    ap.add_argument("--body", default="anny22", help="body model name (without --refine)")
    ap.add_argument("--iters", type=int, default=150)
    ap.add_argument("--lr", type=float, default=0.02)
    ap.add_argument("--optimizer", choices=("adam", "lbfgs"), default="adam")
    ap.add_argument("--num-roots", type=int, choices=(1, 24), default=24)
    ap.add_argument("--batch-size", type=int, default=4)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")

    from arteq.data import BodyScanDataModule

    module = None
    if args.refine:
        run_dir = Path(args.refine)
        from arteq.training.module import ArtEqModule

        ckpt = find_checkpoint(run_dir)
        module = ArtEqModule.load_from_checkpoint(str(ckpt), map_location="cpu", weights_only=True).eval()
        run_cfg = load_run_data_config(run_dir)
        data_cfg = {k: v for k, v in run_cfg["data"].items() if k not in ("_target_", "body_model")}
        body_cfg = dict(module.hparams.body_model)
        method = "ArtEq + refinement"
    elif args.data_from:
        run_cfg = load_run_data_config(Path(args.data_from))
        data_cfg = {k: v for k, v in run_cfg["data"].items() if k not in ("_target_", "body_model")}
        body_cfg = {k: v for k, v in run_cfg["body_model"].items() if k != "_target_"}
        method = "Optimisation (Chamfer)"
    else:
        data_cfg = {"source": "synthetic", "num_points": args.num_points}
        body_cfg = {"name": args.body}
        method = "Optimisation (Chamfer)"
    # Test sets are drawn per index from fixed seeds: the first `samples` clouds are the run's first ones.
    data_cfg.update(
        eval_batch_size=args.batch_size, batch_size=args.batch_size, num_workers=0, test_size=args.samples
    )
    dm = BodyScanDataModule(body_model=body_cfg, **data_cfg)
    body = module.body if module is not None else dm.body
    fit_kwargs = {"iters": args.iters, "lr": args.lr, "optimizer": args.optimizer}
    if module is None:
        fit_kwargs["num_roots"] = args.num_roots
    result = evaluate_fitter(dm, body, fit_kwargs, module=module, max_samples=args.samples)
    summary = {
        "task_name": "fitting",
        "method": method,
        "metrics": result["metrics"],
        "fit": result["fit"],
        "parameters": sum(p.numel() for p in module.net.parameters()) if module is not None else 0,
        "config": {"fitter": fit_kwargs, "data": data_cfg, "body_model": body_cfg, "refine": args.refine},
    }
    from arteq.eval import metrics_table, write_metrics

    out = Path(args.out)
    write_metrics(summary, out)
    timing = ", ".join(
        f"{s}: {v['seconds_per_sample']:.1f} s/sample, {v['mean_iterations']:.0f} it"
        for s, v in result["fit"].items()
    )
    (out / "metrics.md").write_text(
        f"# {method}: test metrics\n\n{metrics_table({method: result['metrics']})}\n\n{timing}\n"
    )
    log.info("fit timing: %s", json.dumps(result["fit"]))
    return summary


if __name__ == "__main__":
    main()
