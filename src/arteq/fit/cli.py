"""``arteq-fit INPUT... --out DIR``: fit the body model to scans (files, folders, globs).

Writes ``<name>.obj`` (fitted mesh, scan frame and units), ``<name>.npz`` (parameters, joints, per-point
parts, clutter, Anny parameters), ``<name>.json`` (the same in words), ``<name>.png`` (preview) per scan
and ``summary.json`` / ``summary.csv`` for the run. Exit code 0 when every input was fitted (or skipped),
1 when any failed, 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import sys


def build_parser() -> argparse.ArgumentParser:
    from arteq.io.scans import SUFFIXES, UNITS

    ap = argparse.ArgumentParser(
        prog="arteq-fit",
        description=f"Fit the body model to point clouds or meshes ({' '.join(SUFFIXES)}) "
        "or depth images (16-bit .png in mm, .npy in m).",
        epilog="Try it: python -m arteq.fit.demo --out demo && arteq-fit demo/scans --out demo/fits",
    )
    ap.add_argument("inputs", nargs="+", metavar="INPUT", help="scan files, folders (recursive) or globs")
    ap.add_argument("--out", "-o", required=True, help="output folder")
    ap.add_argument(
        "--ckpt",
        default=None,
        help="checkpoint file or pretrained name (default: anny_scan, the scan-fitting model; anny22: the "
        "research model, adults in everyday poses only)",
    )
    ap.add_argument("--refine", action=argparse.BooleanOptionalAction, default=True,
                    help="refine the network's fit against the scan (default: on)")  # fmt: skip
    ap.add_argument("--points", type=int, default=5000, help="input resampled to this many points (5000)")
    ap.add_argument("--units", choices=tuple(UNITS), default="m", help="units of the input files (m)")
    ap.add_argument("--key", default=None, help="array name in .npz inputs (default: points)")
    ap.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    ap.add_argument("--batch-size", type=int, default=4, help="scans fitted together (4)")
    ap.add_argument("--iters", type=int, default=None, help="refinement iterations (default 60)")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="refine_set",
        help="a refinement setting (arteq.fit.refine.RefineConfig), e.g. --set swing_at=-1; repeatable",
    )
    ap.add_argument("--shape-betas", type=int, default=None, metavar="N",
                    help="shape coefficients the refinement fits (default: all 32 for the anny_allages body "
                         "of the default model, the network's own otherwise)")  # fmt: skip
    ap.add_argument("--net-draws", type=int, default=None, metavar="K",
                    help="the network's pose and shape averaged over K random subsets of each scan (default: "
                    "arteq.fit.api.NET_DRAWS)")  # fmt: skip
    ap.add_argument("--retries", type=int, default=None, metavar="K",
                    help="fit a doubtful full scan K more times, from turned readings of the scan, and keep "
                    "the fit that explains it best (default: arteq.fit.api.RETRIES; 0: never)")  # fmt: skip
    ap.add_argument("--retry-above", type=float, default=None, metavar="CM",
                    help="only fits whose surface score is above this (cm; default: "
                    "arteq.fit.api.RETRY_ABOVE_CM)")  # fmt: skip
    ap.add_argument("--no-torso-retry", dest="torso_retry", action="store_false", default=None,
                    help="no retry from the network's reading with the torso turned round (default: one, "
                    "arteq.fit.api.TORSO_RETRY)")  # fmt: skip
    ap.add_argument("--clothing", type=float, default=None, metavar="CM",
                    help="the people wear clothes about CM thick over the skin (a T-shirt and "
                    "jeans: about 1; sweats: 2): fit the body under them (default: the scanned "
                    "surface)")  # fmt: skip
    ap.add_argument("--clothing-parts", default=None, metavar="JOINTS",
                    help="the parts the clothes cover, joint names comma-separated (default: trunk, upper "
                    "arms, thighs and shins: arteq.fit.clothing.COVERED)")  # fmt: skip
    ap.add_argument("--hands", action=argparse.BooleanOptionalAction, default=True,
                    help="fit each hand's finger curl and wrist last (bodies built from Anny; default: on); "
                    "--no-hands leaves the hands flat")  # fmt: skip
    ap.add_argument("--preview", action=argparse.BooleanOptionalAction, default=True, help="write <name>.png")
    ap.add_argument("--overwrite", action="store_true", help="replace existing outputs (else skip them)")
    ap.add_argument("--check", action=argparse.BooleanOptionalAction, default=True,
                    help="refuse scans that are not one body, flag uncertain fits (default: on)")  # fmt: skip
    ap.add_argument("--strict", action="store_true",
                    help="refuse uncertain fits too (status refused, nothing written)")  # fmt: skip
    ap.add_argument("--clean", action=argparse.BooleanOptionalAction, default=True,
                    help="remove floors, walls, stray points, other objects first (default: on)")  # fmt: skip
    ap.add_argument("--objects", action=argparse.BooleanOptionalAction, default=True,
                    help="full scans whose fit the check doubts: look for flat objects touching the body "
                    "(a chair, a stool) among the points off the fit, fit again without them "
                    "(default: on)")  # fmt: skip
    ap.add_argument("--anny", action=argparse.BooleanOptionalAction, default=None,
                    help="Anny phenotype, pose and body measurements per fit (default: when the anny "
                    "package is installed and the body is an Anny body; --anny: required)")  # fmt: skip
    ap.add_argument("--crossing", action=argparse.BooleanOptionalAction, default=True,
                    help="full scans: refit a doubtful fit with left / right limb pairs swapped, and with "
                    "a lost limb placed on the points off the fit; keep one that explains the scan better "
                    "(crossed arms; default: on)")  # fmt: skip
    ap.add_argument("--crossing-set", action="append", default=[], metavar="KEY=VALUE",
                    help="a setting of that step (arteq.fit.crossing.CrossingConfig), e.g. --crossing-set "
                    "torso_once=false (the lost-torso step in every fit of a lost scan, not once on the fit "
                    "its retries keep: slower); repeatable")  # fmt: skip
    ap.add_argument("--second-start", default=None, metavar="MODEL",
                    help="full scans: also refine from this model's pose and keep the fit that explains the "
                    "scan better (default: anny22 for a model on the all-ages body)")  # fmt: skip
    ap.add_argument("--no-second-start", dest="second_start", action="store_false",
                    help="refine from the network's own pose only (faster)")  # fmt: skip
    ap.add_argument("--partial", action=argparse.BooleanOptionalAction, default=None,
                    help="scans are one camera's view (--partial) or full surfaces (--no-partial); default: "
                    "detected per scan, a depth image is partial")  # fmt: skip
    ap.add_argument("--view-dir", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                    help="from the body toward the camera, scan frame (implies --partial)")  # fmt: skip
    depth = ap.add_argument_group("depth images (else from <name>.json or intrinsics.json beside each image)")
    for k in ("fx", "fy", "cx", "cy"):
        depth.add_argument(f"--{k}", type=float, default=None, help=f"camera intrinsics: {k} in pixels")
    depth.add_argument("--depth-scale", type=float, default=None,
                       help="metres per unit of a 16-bit PNG (default 0.001: millimetres)")  # fmt: skip
    depth.add_argument("--depth-range", type=float, nargs=2, default=None, metavar=("NEAR", "FAR"),
                       help="the person's depth band in metres (default: 0.5 m in front of to 1.5 m behind "
                       "the nearest depths, 15th percentile, of the image's central third)")  # fmt: skip
    ap.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None, help="progress bar")
    ap.add_argument(
        "--threads",
        type=int,
        default=None,
        help="torch CPU threads per process (default: torch's; with --jobs, the cores shared out)",
    )
    ap.add_argument(
        "--jobs",
        "-j",
        type=int,
        default=None,
        help="processes fitting batches side by side (default: one per CPU core on the CPU, or per "
        "--threads cores, at most 8 and one per 1.5 GB of free memory; one on a GPU). Each fit's steps are "
        "too small to share threads well: on 2 cores two one-thread processes fit a folder faster than one "
        "two-thread process",
    )
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.points < 200:
        print(f"arteq-fit: --points must be >= 200, got {args.points}", file=sys.stderr)
        return 2
    if args.jobs is not None and args.jobs < 1:
        print(f"arteq-fit: --jobs must be >= 1, got {args.jobs}", file=sys.stderr)
        return 2
    if args.batch_size < 1:
        print(f"arteq-fit: --batch-size must be >= 1, got {args.batch_size}", file=sys.stderr)
        return 2
    import torch  # heavy imports only after the arguments are known good

    from arteq.fit.api import Fitter
    from arteq.fit.clean import CleanConfig
    from arteq.fit.depth import DepthOptions
    from arteq.fit.files import auto_jobs, fit_files
    from arteq.fit.refine import RefineConfig

    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        cfg = RefineConfig.from_strings(args.refine_set)
        crossing = args.crossing
        if args.crossing_set:
            if not crossing:
                raise ValueError("--crossing-set sets the crossed-limb step: it cannot go with --no-crossing")
            from arteq.fit.crossing import CrossingConfig

            crossing = CrossingConfig.from_strings(args.crossing_set)
        if args.iters is not None:
            cfg.iters = args.iters
        clothing = None
        if args.clothing is not None or args.clothing_parts is not None:
            from arteq.fit.clothing import COVERED, ClothingConfig

            if args.clothing is None:
                raise ValueError("--clothing-parts needs --clothing CM")
            clothing = ClothingConfig(thickness_cm=args.clothing, parts=args.clothing_parts or COVERED)
        kwargs = dict(ckpt=args.ckpt, device=args.device, refine=args.refine, points=args.points,
                      refine_config=cfg, check=args.check, clean=args.clean, anny=args.anny,
                      strict=args.strict, partial=args.partial, view_dir=args.view_dir,
                      crossing=crossing, second_start=args.second_start,
                      shape_betas=args.shape_betas, net_draws=args.net_draws, retries=args.retries,
                      retry_above_cm=args.retry_above, clothing=clothing, torso_retry=args.torso_retry,
                      hands=args.hands,
                      clean_config=CleanConfig(objects=args.objects))  # fmt: skip
        fitter = Fitter(**kwargs)
        jobs = args.jobs or auto_jobs(args.device, args.threads)
    except (FileNotFoundError, ValueError, RuntimeError) as exc:
        print(f"arteq-fit: {exc}", file=sys.stderr)
        return 2
    summary = fit_files(
        args.inputs, args.out, fitter=fitter, units=args.units, key=args.key, preview=args.preview,
        overwrite=args.overwrite, batch_size=args.batch_size, progress=args.progress,
        depth=DepthOptions(intrinsics={k: getattr(args, k) for k in ("fx", "fy", "cx", "cy")},
                           depth_scale=args.depth_scale, depth_range_m=args.depth_range),
        jobs=jobs, threads=args.threads, **(kwargs if jobs > 1 else {}),
    )  # fmt: skip
    print(summary.line())
    return 1 if summary.failed else 0


if __name__ == "__main__":
    sys.exit(main())
