"""``ngp predict FOLDER | --list FILE --out results.jsonl``: every image of a collection calibrated into a JSON Lines
file, on the CPU or GPUs, in one or several processes on one or several machines, resumable.

Its arguments are parsed and checked without importing torch or Lightning (:func:`check_predict`); the run imports
:mod:`ngp_kornia.predict` (:func:`predict_command`).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from ngp_kornia.cli_colmap import check_colmap, write_colmap
from ngp_kornia.preflight import check_extra, check_folder

__all__ = ["add_predict_arguments", "check_predict", "predict_command"]


def add_predict_arguments(pred: argparse.ArgumentParser) -> None:
    """The options of ``ngp predict`` but the priors and settings (which it shares with ``ngp calibrate``)."""
    pred.add_argument("folder", nargs="?", help="folder of images (or give --list)")
    pred.add_argument("--list", dest="image_list", metavar="FILE",
                      help="image paths instead (a line each, or a .csv)")
    pred.add_argument("-o", "--out", metavar="JSONL", required=True,
                      help="the file of rows to write (replaces only a file of such rows)")
    pred.add_argument("--resume", action="store_true", help="continue a stopped run: the images without a row")
    pred.add_argument("--accelerator", metavar="DEVICE", choices=("cpu", "gpu", "auto"), default="cpu",
                      help="cpu, gpu, or auto (a GPU if any)")
    pred.add_argument("--devices", metavar="N", type=int, default=1, help="CPU processes or GPUs per machine")
    pred.add_argument("--num-nodes", metavar="N", type=int, default=1, help="machines, each running this command")
    pred.add_argument("--workers", metavar="N", type=int, default=0, help="processes per device reading images")
    pred.add_argument("--weights", metavar="NAME", default="default",
                      help="default, none, zsnet, fsnet, full, or a .pt file")
    pred.add_argument("--recursive", action="store_true", help="also calibrate the images of sub-folders")
    pred.add_argument("--batch-size", metavar="N", type=int, default=1, help="images per loader batch")
    pred.add_argument("--seed", metavar="N", type=int, default=0, help="seed of the random sampling")


def check_predict(args: argparse.Namespace) -> int | None:
    """The checks of ``ngp predict``'s arguments made before anything heavy is imported: a usage error is one line
    and exit status 2, a missing extra or input exit status 1 (None: go on)."""
    usage = None
    for option, value, least in (("--devices", args.devices, 1), ("--batch-size", args.batch_size, 1),
                                 ("--num-nodes", args.num_nodes, 1), ("--workers", args.workers, 0)):
        if value < least:
            usage = usage or f"{option} must be at least {least}, got {value}"
    if (args.folder is None) == (args.image_list is None):
        usage = usage or ("give a folder or --list FILE, not both" if args.folder else "give a folder or --list FILE")
    if args.image_list is not None and args.recursive:
        usage = usage or "--recursive is for a folder; a --list names its files"
    if usage:
        print(f"ngp: error: {usage}", file=sys.stderr)
        return 2
    try:
        check_extra(["lightning"], "ngp predict", "train")
        if args.folder is not None:
            check_folder(args.folder, args.recursive)
        elif not Path(args.image_list).is_file():
            raise FileNotFoundError(f"--list {args.image_list}: no such file; give a text file of one image path "
                                    "per line, or a .csv file with a 'path' column")
        check_colmap(args)
    except (ImportError, OSError, ValueError) as err:
        print(f"ngp: error: {_one_line(err)}", file=sys.stderr)
        return 1
    return None


def predict_command(args: argparse.Namespace, config, priors, user_errors: tuple) -> int:
    """Run ``ngp predict`` (``config``: the ParserConfig of the setting options; ``priors``: the Priors of the prior
    options; ``user_errors``: the exceptions reported as one line); its exit status."""
    from ngp_kornia import predict

    try:
        args.accelerator = predict.resolve_accelerator(args.accelerator, args.devices)
    except predict.AcceleratorError as err:
        print(f"ngp: error: {err}", file=sys.stderr)
        return 2
    forked = predict.forks_processes(args.devices, args.num_nodes)
    if args.accelerator == "cpu" and forked and args.devices > (cores := predict.usable_cores()):
        print(f"ngp: warning: --devices {args.devices} capped at {cores}, the CPU cores available", file=sys.stderr)
        args.devices = cores
    for name in ("lightning.pytorch", "lightning.fabric"):  # the rows go to --out; keep the terminal quiet
        logging.getLogger(name).setLevel(logging.WARNING)
    try:
        counts = _run(args, config, priors)
    except user_errors as err:
        print(f"ngp: error: {_one_line(err)}", file=sys.stderr, flush=True)
        return 1
    return _report(counts, args)


def _run(args: argparse.Namespace, config, priors) -> dict:
    from ngp_kornia import predict
    from ngp_kornia.data.folder import ImageFolder
    from ngp_kornia.data.image_list import ImageList, read_image_list

    if args.folder is not None:
        images = ImageList.from_folder(ImageFolder(args.folder, recursive=args.recursive))
    else:
        images = read_image_list(args.image_list)
    settings = {"weights": args.weights, "seed": args.seed, "config": config, "priors": priors, "exif": args.exif,
                "same_camera": args.same_camera}
    plan = predict.plan_run(images, args.out, args.resume, **settings)
    if args.resume and _first_process():
        done = f"{plan.done} of {len(images)} images have their row" if plan.keep else "no unfinished run to continue"
        print(f"ngp: resuming {args.out}: {done}; calibrating {len(plan.todo)}", file=sys.stderr, flush=True)
    return predict.run_plan(
        plan, devices=args.devices, batch_size=args.batch_size, num_workers=args.workers,
        progress_bar=sys.stderr.isatty(), accelerator=args.accelerator, num_nodes=args.num_nodes,
    )


def _first_process() -> bool:
    """Whether this command is the first process of its run (the others say nothing before the run)."""
    import os

    return all(os.environ.get(name, "0") == "0" for name in ("NODE_RANK", "LOCAL_RANK", "RANK", "SLURM_PROCID"))


def _report(counts: dict, args: argparse.Namespace) -> int:
    """Say how the run ended, and hand the finished rows on (``--colmap``); the exit status."""
    out, rank = args.out, counts["rank"]
    if counts["interrupted"]:
        if rank == 0:
            print(f"ngp: interrupted: the {counts['images']} images finished are in {out}; run the same command "
                  "with --resume to calibrate the rest", file=sys.stderr, flush=True)
        return 130
    if rank != 0:
        print(f"process {rank}: {counts['images']} rows calibrated; process 0 writes every row to {out}")
        return 0
    print(f"{counts['images']} rows written to {out}")
    if args.colmap:  # every image has its row: the cameras and gravity priors into the database
        write_colmap(args.colmap, out)
    if counts["errors"]:
        print(
            f"ngp: error: {counts['errors']} of {counts['images']} images could not be read; "
            f'see the rows with "error" in {out}',
            file=sys.stderr,
        )
        return 1
    return 0


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__
