"""The horizon refinement (``ParserConfig.refine_horizon``) on and off, on the same frame searches.

For every image the segments are detected once and the frame search runs once per sampling seed; the refinement
is then applied to that very calibration, so "off" and "on" differ only by the refinement. Sets:

* ``--yud ROOT``: York Urban, against both ground-truth horizons (``calibrated``: ``K^-T up`` with the true K and
  ``vp_orthogonal``; ``published``: the line through the two raw horizontal VPs ``(K v_a) x (K v_b)``, see the
  dataset's README); up-vector and FoV errors against the calibrated camera.
* ``--manifest CSV``: any CSV manifest with horizons (e.g. the Eurasian Cities development manifest).
* ``--rendered DIR``: a folder written by ``ngp render``.

Usage::

    python benchmarks/horizon_refine.py --yud YorkUrbanDB --manifest EurasianCities/manifest.csv \\
        --rendered render_dir --limit-rendered 300 --seeds 0,1,2,3,4 [--weights default] [--out r.json] \
        [--refine margin=0.05 --refine focal_scales=1.0/1.1,frame_roll=true] [--timing N]

Each ``--refine`` is one variant, keyword arguments of :func:`ngp_kornia.pipeline.horizon.refine_horizon`
(default: one variant "on" with the shipped settings).

Seconds per image (``--timing N``): ``ngp_kornia.calibrate`` on the first N images of each real set, with the
refinement off and on interleaved image by image, in the same process (the ratio is what counts: other jobs share
the machine).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from ngp_kornia import calibrate
from ngp_kornia.api import load_parser
from ngp_kornia.data.manifest import CSVManifest
from ngp_kornia.data.yud import YorkUrbanDB, _loadmat
from ngp_kornia.io import read_rgb
from ngp_kornia.metrics import fov_error, horizon_auc, horizon_error, up_vector_error
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.pipeline.horizon import refine_horizon
from ngp_kornia.pipeline.segments import detect_segments


def yud_samples(root: Path) -> list[dict]:
    """York Urban images with the calibrated and the published horizon (pixels), K, up and fov_v."""
    out = []
    flip = np.diag([1.0, -1.0, 1.0])
    for s in YorkUrbanDB(root):
        vp = np.asarray(_loadmat(s.image_path.parent / f"{s.name}GroundTruthVP_CamParams.mat", ["vp"])["vp"], float)
        K = s.K.numpy()
        a, b = K @ flip @ vp[:, 0], K @ flip @ vp[:, 2]
        published = torch.as_tensor(np.cross(a, b), dtype=torch.float64)
        out.append(
            dict(name=s.name, path=s.image_path, h=s.height, w=s.width, horizons={"calibrated": s.horizon,
                 "published": published}, up=s.up, fov_v=s.fov_v)
        )
    return out


def manifest_samples(path: Path) -> list[dict]:
    return [
        dict(name=s.image_path.stem, path=s.image_path, h=s.height, w=s.width, horizons={"horizon": s.horizon})
        for s in CSVManifest(path)
        if s.horizon is not None
    ]


def rendered_samples(root: Path) -> list[dict]:
    from calibration import load_rendered

    return [
        dict(name=s.name, path=s.image_path, h=s.height, w=s.width, horizons={"horizon": s.horizon}, up=s.up,
             fov_v=s.fov_v)
        for s in load_rendered(root)
    ]


def parse_variant(spec: str) -> dict:
    """``key=value,...`` -> keyword arguments of :func:`refine_horizon` (numbers; true / false; tuples as a/b)."""
    out = {}
    for item in filter(None, spec.split(",")):
        key, _, value = item.partition("=")
        if "/" in value:  # a tuple, e.g. focal_scales=0.9/1.1
            out[key] = tuple(float(x) for x in value.split("/"))
            continue
        if value.lower() in ("true", "false"):
            out[key] = value.lower() == "true"
            continue
        out[key] = int(value) if value.lstrip("-").isdigit() else float(value)
    return out


def run_set(samples: list[dict], weights: str, seeds: list[int], variants: dict[str, dict]) -> dict:
    """Per seed and variant (off, then each refinement variant): per-image horizon errors for each ground truth,
    up and FoV errors."""
    cfg = ParserConfig()
    parser = load_parser(weights, cfg)
    res: dict = {}
    refine_seconds = 0.0
    for i, s in enumerate(samples):
        rgb = read_rgb(s["path"])
        image = torch.from_numpy(rgb).permute(2, 0, 1)[None].float().div(255.0)
        segments, mask = detect_segments(rgb, cfg)
        for seed in seeds:
            parser.config = replace(cfg, seed=seed, refine_horizon=False)
            with torch.no_grad():
                off = parser(image, segments, mask)
                cals = {"off": off}
                for name, kwargs in variants.items():
                    t0 = time.perf_counter()
                    cals[name] = refine_horizon(off, segments, mask, **kwargs)
                    refine_seconds += time.perf_counter() - t0
            for variant, cal in cals.items():
                r = res.setdefault(seed, {}).setdefault(variant, {})
                for gt, line in s["horizons"].items():
                    e = horizon_error(cal.horizon.double(), line[None], s["h"], s["w"])
                    r.setdefault(gt, []).append(float(e[0]))
                if "up" in s:
                    r.setdefault("up", []).append(float(up_vector_error(cal.up.double(), s["up"][None])[0]))
                    fov = torch.tensor([s["fov_v"]], dtype=torch.float64)
                    r.setdefault("fov", []).append(float(fov_error(cal.fov_v.double(), fov)[0]))
        print(f"\r{i + 1}/{len(samples)} {s['name']}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    res["refine_seconds_per_call"] = refine_seconds / max(1, len(samples) * len(seeds) * len(variants))
    return res


def summary(res: dict, seeds: list[int]) -> dict:
    """Mean and range over seeds of the horizon AUC (%) per ground truth, median up / FoV errors (degrees)."""
    out = {}
    for variant in res[seeds[0]]:
        keys = res[seeds[0]][variant].keys()
        for key in keys:
            if key in ("up", "fov"):
                vals = [statistics.median(res[s][variant][key]) for s in seeds]
                label = f"{key} median (deg)"
            else:
                vals = [100 * float(horizon_auc(res[s][variant][key])) for s in seeds]
                label = f"horizon AUC {key} (%)"
            out.setdefault(label, {})[variant] = (statistics.mean(vals), min(vals), max(vals))
    return out


def timing(samples: list[dict], weights: str, n: int) -> dict:
    """Seconds per image of calibrate() with the refinement off and on, interleaved image by image after one warm-up
    call each: wall time, and the process's CPU time (less sensitive to other jobs on the machine)."""
    wall = {False: 0.0, True: 0.0}
    cpu = {False: 0.0, True: 0.0}
    for flag in (False, True):
        calibrate(str(samples[0]["path"]), weights=weights, config=ParserConfig(refine_horizon=flag))
    for i, s in enumerate(samples[:n]):
        for flag in ((False, True) if i % 2 == 0 else (True, False)):
            t0, c0 = time.perf_counter(), time.process_time()
            calibrate(str(s["path"]), weights=weights, config=ParserConfig(refine_horizon=flag))
            wall[flag] += time.perf_counter() - t0
            cpu[flag] += time.process_time() - c0
    count = min(n, len(samples))
    return {
        "off": wall[False] / count, "on": wall[True] / count, "cpu_off": cpu[False] / count,
        "cpu_on": cpu[True] / count, "images": count,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--yud", type=Path)
    ap.add_argument("--manifest", type=Path)
    ap.add_argument("--rendered", type=Path)
    ap.add_argument("--limit-rendered", type=int, default=None)
    ap.add_argument("--limit", type=int, default=None, help="first N images of every set")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--weights", default="default")
    ap.add_argument("--timing", type=int, default=0, help="time calibrate() on the first N images of each real set")
    ap.add_argument("--out", type=Path)
    ap.add_argument(
        "--refine", action="append", default=None,
        help="a refinement variant as refine_horizon keyword arguments, e.g. margin=0.02,num_peaks=6; repeatable "
        "(default: one variant 'on' with the defaults)",
    )
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    variants = {spec: parse_variant(spec) for spec in args.refine} if args.refine else {"on": {}}
    sets = {}
    if args.yud:
        sets["York Urban"] = yud_samples(args.yud)
    if args.manifest:
        sets[args.manifest.parent.name or str(args.manifest)] = manifest_samples(args.manifest)
    if args.rendered:
        sets["renders"] = rendered_samples(args.rendered)[: args.limit_rendered]
    if not sets:
        ap.error("give at least one of --yud, --manifest, --rendered")
    payload: dict = {"command": " ".join(sys.argv), "weights": args.weights, "seeds": seeds, "sets": {}}
    for name, samples in sets.items():
        samples = samples[: args.limit]
        res = run_set(samples, args.weights, seeds, variants)
        summ = summary(res, seeds)
        payload["sets"][name] = {"images": len(samples), "summary": summ, "refine_seconds_per_call":
                                 res["refine_seconds_per_call"], "per_seed": {str(k): v for k, v in res.items()
                                                                                if k in seeds}}
        print(f"\n{name}: {len(samples)} images, seeds {args.seeds}, weights {args.weights} "
              f"(refinement {1000 * res['refine_seconds_per_call']:.1f} ms per call)")
        print("| metric | off: mean [min, max] | " + " | ".join(f"{v}: mean [min, max]" for v in variants) + " |")
        print("|---|---|" + "---|" * len(variants))
        for label, v in summ.items():
            print(f"| {label} | " + " | ".join(f"{m:.2f} [{lo:.2f}, {hi:.2f}]" for m, lo, hi in v.values()) + " |")
        if args.timing and name != "renders":
            t = timing(samples, args.weights, args.timing)
            payload["sets"][name]["timing"] = t
            print(f"calibrate() seconds per image on {t['images']} images: wall off {t['off']:.4f}, on {t['on']:.4f} "
                  f"(ratio {t['on'] / t['off']:.3f}); CPU off {t['cpu_off']:.4f}, on {t['cpu_on']:.4f} "
                  f"(ratio {t['cpu_on'] / t['cpu_off']:.3f})")
    if args.out:
        args.out.write_text(json.dumps(payload, indent=1, default=str))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
