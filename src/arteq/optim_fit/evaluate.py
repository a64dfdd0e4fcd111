"""Evaluate the optimisation fitter on test_id / test_ood with the training metrics.

``python -m arteq.optim_fit.evaluate --out experiments/fitting/opt [--samples 16] [--num-points 1000]``
fits from the standard start (rest pose, 24 root orientations tried, centroid translation);
``--refine RUN_DIR`` starts from that ArtEq run's prediction instead (ArtEq + refinement) and uses the
run's data configuration. Writes ``metrics.json`` / ``metrics.md`` in the format of
:func:`arteq.io.runs.write_metrics` (read by ``python -m arteq.report``), with ``method`` and ``fit``
(iterations, seconds per sample) added. Part accuracy: each point takes the part label of its nearest
fitted vertex.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from typing import Any

import torch

from arteq.geometry.pointops import knn
from arteq.io import runs
from arteq.optim_fit.chamfer import fit_body
from arteq.results import TEST_SPLITS, metric_values, metrics_markdown
from arteq.training.metrics import BodyFitMetrics

log = logging.getLogger("arteq.optim_fit")


def loader_split_names(datamodule) -> tuple[str, ...]:
    """The split name of each of ``datamodule.test_dataloader()``'s loaders, in order: the datamodule's
    ``test_loader_splits`` when it has them, else its ``test_splits`` then ``view_splits`` (the chosen
    subset, not all of :data:`TEST_SPLITS`), else :data:`TEST_SPLITS`."""
    names = getattr(datamodule, "test_loader_splits", None)
    if names is None:
        names = (*getattr(datamodule, "test_splits", TEST_SPLITS), *getattr(datamodule, "view_splits", ()))
    return tuple(names)


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
    loaders = datamodule.test_dataloader()
    names = loader_split_names(datamodule)
    if len(names) != len(loaders):
        raise ValueError(
            f"the datamodule gave {len(loaders)} test loaders for the {len(names)} splits {list(names)}"
        )
    for split, loader in zip(names, loaders):
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
        out["metrics"][split] = metric_values(metric.compute())
        out["fit"][split] = {
            "samples": n,
            "mean_iterations": sum(iters) / len(iters),
            "seconds_per_sample": seconds / n,
        }
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(
        prog="python -m arteq.optim_fit.evaluate", description=__doc__.split("\n\n")[0]
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
    method = "Optimisation (Chamfer)"
    if args.refine or args.data_from:
        run_cfg = runs.read_config(args.refine or args.data_from)
        data_cfg = runs.data_kwargs(run_cfg)
        body_cfg = runs.body_config(run_cfg)
    else:
        data_cfg = {"source": "synthetic", "num_points": args.num_points}
        body_cfg = {"name": args.body}
    if args.refine:
        module = runs.load_module(args.refine)
        body_cfg = dict(module.hparams.body_model)
        method = "ArtEq + refinement"
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
    timing = ", ".join(
        f"{s}: {v['seconds_per_sample']:.1f} s/sample, {v['mean_iterations']:.0f} it"
        for s, v in result["fit"].items()
    )
    runs.write_metrics(args.out, summary, metrics_markdown(method, {method: result["metrics"]}, note=timing))
    log.info("fit timing: %s", json.dumps(result["fit"]))
    return summary


if __name__ == "__main__":
    main()
