"""Which end is up, read against the answered horizon: a study of a cue for photos turned by half a turn.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/upright_horizon_cue.py --cache lines_cache.pt --features cue.pt

The orientation check tells a quarter turn well from the segments but an upside-down photo from an upright one
poorly. The parser's answer for a photo read as upright gives every pixel an elevation above or below the horizon,
and a photo turned by 180 degrees is answered with these elevations of opposite sign. So statistics that are
brighter, bluer, smoother or richer in segments above the horizon than below, each as its covariance with the sign
and with the size of the elevation (sixteen numbers that change sign with the elevation), are a cue between the
two readings that no thumbnail of 64 pixels holds: the horizon. A logistic model without intercept (so the two
readings stay symmetric) learns it from the ``train`` part of the photo folder, each photo upright and upside down;
its weight decay and its weight in the fused reading are chosen on the ``calibrate`` part; York Urban and ECD are
reported. The cache is ``benchmarks/upright_lines_cache.py``'s (segments, thumbnail logits); the answers (default
weights, seed 0, the check off) are computed here once and kept in ``--features``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from upright_calibration import decisions
from upright_lines import raw_views, turn_segments

from ngp_kornia import calibrate
from ngp_kornia.io import read_image_file
from ngp_kornia.nets.weights import load_network
from ngp_kornia.pipeline.upright_check import weigh_by_pitch

TAU = 0.1  # radians: the elevation's sign is tanh(elevation / TAU)
SETS = ("calibrate", "test", "yud", "ecd")


def elevations(out, points: np.ndarray) -> np.ndarray:
    """The answered elevation (radians) of the rays through pixels ``points`` (..., 2)."""
    k, up = out.K.double().numpy(), out.up.double().numpy()
    ray = np.stack([(points[..., 0] - k[0, 2]) / k[0, 0], (points[..., 1] - k[1, 2]) / k[1, 1],
                    np.ones(points.shape[:-1])], -1)  # fmt: skip
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    return np.arcsin(np.clip(ray @ up, -1.0, 1.0))


def pixel_cues(rgb: np.ndarray, out) -> list[float]:
    """Covariances of brightness, saturation, blue over red, gradient and the brightest tenth with the sign and the
    size of the elevation, on a view of about 128 pixels, and the mean sign (how much lies above the horizon)."""
    step = max(1, round(max(rgb.shape[:2]) / 128))
    small = rgb[::step, ::step].astype(np.float32) / 255.0
    ys, xs = np.mgrid[0 : small.shape[0], 0 : small.shape[1]] * step
    elev = elevations(out, np.stack([xs, ys], -1).astype(np.float64))
    lum = small.mean(-1)
    grad = np.hypot(cv2.Sobel(lum, cv2.CV_32F, 1, 0), cv2.Sobel(lum, cv2.CV_32F, 0, 1))
    stats = (lum, cv2.cvtColor(small, cv2.COLOR_RGB2HSV)[..., 1], small[..., 2] - small[..., 0], grad,
             (lum > np.quantile(lum, 0.9)).astype(np.float32))  # fmt: skip
    cues = []
    for s in stats:
        for e in (np.tanh(elev / TAU), elev):
            cues.append(float(np.mean(s * e) - np.mean(s) * np.mean(e)))
    return [*cues, float(np.tanh(elev / TAU).mean())]


def segment_cues(seg: np.ndarray, out) -> list[float]:
    """Length-weighted mean sign of the segments' elevation (all, near the answered vertical, the rest), their mean
    elevation, and the answered pitch over 30 degrees."""
    seg = seg[np.linalg.norm(seg[:, 1] - seg[:, 0], axis=-1) >= 1.0]
    if not len(seg):
        return [0.0] * 4 + [float(out.pitch) / 30.0]
    length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=-1)
    elev = elevations(out, seg.mean(1).astype(np.float64))
    roll = math.radians(float(out.roll))
    vertical = np.abs((seg[:, 1] - seg[:, 0]) / length[:, None] @ np.array([math.sin(roll), -math.cos(roll)])) > 0.8
    sign, total = length * np.tanh(elev / TAU), length.sum()
    return [float(sign.sum() / total), float(sign[vertical].sum() / total), float(sign[~vertical].sum() / total),
            float((length * elev).sum() / total), float(out.pitch) / 30.0]  # fmt: skip


def set_cues(data: dict, turns: list[int]) -> dict:
    """Cues and answered pitch of every photo of a set in each of ``turns`` (quarter turns, as ``np.rot90``)."""
    cues, pitch = [], []
    for path, seg in zip(data["names"], data["segments"], strict=True):
        rgb = read_image_file(path)
        size = torch.tensor([rgb.shape[:2]])
        row, prow = [], []
        for k in turns:
            image = np.ascontiguousarray(np.rot90(rgb, k))
            out = calibrate(image, "default", seed=0, config={"upright.enabled": False})
            turned = turn_segments(torch.as_tensor(seg, dtype=torch.float64)[None], size, k)[0][0].numpy()
            row.append(pixel_cues(image, out) + segment_cues(turned, out))
            prow.append(float(out.pitch))
        cues.append(row)
        pitch.append(prow)
    return {"cues": torch.tensor(cues, dtype=torch.float64), "pitch": torch.tensor(pitch)}


def all_cues(cache: dict, path: Path) -> dict:
    """The cues of the train part (upright and upside down) and of every reported set (four turns), cached."""
    if path.exists():
        return torch.load(path, weights_only=False)
    cues = {}
    for name in ("train", *SETS):
        start = time.perf_counter()
        cues[name] = set_cues(cache[name], [0, 2] if name == "train" else [0, 1, 2, 3])
        print(f"{name}: {len(cache[name]['names'])} photos in {time.perf_counter() - start:.0f} s", flush=True)
    torch.save(cues, path)
    return cues


def fit_cue(x: torch.Tensor, decay: float) -> torch.Tensor:
    """Weights of the logistic model without intercept: upright rows ``x[:, 0]`` against upside-down ``x[:, 1]``."""
    rows = torch.cat([x[:, 0], x[:, 1]])
    label = torch.cat([torch.ones(len(x)), torch.zeros(len(x))]).to(rows)
    w = torch.zeros(rows.shape[1], dtype=rows.dtype, requires_grad=True)
    opt = torch.optim.LBFGS([w], max_iter=200, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = F.binary_cross_entropy_with_logits(rows @ w, label) + decay * w.pow(2).sum()
        loss.backward()
        return loss

    opt.step(closure)
    return w.detach()


def fused_readings(cache: dict, name: str, lines_net) -> tuple[torch.Tensor, torch.Tensor]:
    """(P, 4, 4) log-probabilities of the four turns of every photo in its four turns: the check's fused reading
    (thumbnail network and segments, as shipped) and the thumbnail network's alone."""
    seg, mask, size, _ = raw_views(cache[name], False)
    with torch.no_grad():
        lines = torch.cat([lines_net(seg[i : i + 1], mask[i : i + 1], int(size[i, 0]), int(size[i, 1]))
                           for i in range(len(seg))])  # fmt: skip
        thumb = torch.softmax(cache[name]["logits"][..., :4] / cache["temperature"], -1).reshape(-1, 4)
        fused = torch.log(lines_net.fuse(thumb, lines))
    return fused.reshape(-1, 4, 4).double(), torch.log(thumb).reshape(-1, 4, 4).double()


def half_turn_right(log_odds: torch.Tensor) -> float:
    """Share of upright and upside-down photos whose (P, 4) log-odds of upright against upside down point right."""
    return float(((log_odds[:, 0] > 0).double().mean() + (log_odds[:, 2] < 0).double().mean()) / 2)


def with_cue(fused: torch.Tensor, z: torch.Tensor, weight: float) -> torch.Tensor:
    """The fused (P, 4, 4) log-probabilities with the cue's (P, 4) log-odds split between upright and upside down
    (the quarter turns, which the cue says nothing of, between them)."""
    zero = torch.zeros_like(z)
    return torch.log_softmax(fused + weight * torch.stack([z / 2, zero, -z / 2, zero], -1), -1)


def report(name: str, lp: torch.Tensor, pitch: torch.Tensor, label: str) -> None:
    """The turn read right per true turn and the check's decisions (prior 0.75, sure 0.9, pitch cue 15 degrees)."""
    truth = torch.arange(4)
    probs = torch.cat([lp.exp().reshape(-1, 4), torch.zeros(lp.shape[0] * 4, 1, dtype=lp.dtype)], 1)
    rows = decisions(weigh_by_pitch(probs, pitch.reshape(-1).to(probs), 15.0), truth.repeat(lp.shape[0]), 0.75, 0.9,
                     0.5)  # fmt: skip
    right = (lp.argmax(-1) == truth).double().mean(0)
    print(f"  {name:9s} {label:10s} turn right {' / '.join(f'{100 * r:.0f}' for r in right)}%; right or unsure "
          + " / ".join(f"{100 * r['right or unsure']:.0f}" for r in rows[1:]) + "%; confidently wrong "
          + " / ".join(f"{100 * r['confidently wrong']:.0f}" for r in rows[1:]) + "%")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", required=True, help="benchmarks/upright_lines_cache.py's output")
    ap.add_argument("--features", required=True, help="where the cues are kept (computed when absent)")
    ap.add_argument("--lines", default="ngp_kornia/weights/upright_lines.pt", help="the line reader's weights")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cache = torch.load(args.cache, weights_only=False)
    cues = all_cues(cache, Path(args.features))
    scale = cues["train"]["cues"].pow(2).mean((0, 1)).sqrt().clamp_min(1e-9)
    log_odds = {}
    for decay in (1e-4, 1e-3, 1e-2, 3e-2, 1e-1):
        w = fit_cue(cues["train"]["cues"] / scale, decay)
        z = (cues["calibrate"]["cues"] / scale) @ w
        nll = float(F.softplus(-z[:, 0]).mean() + F.softplus(z[:, 2]).mean()) / 2
        print(f"decay {decay}: calibrate, upright against upside down: NLL {nll:.3f}, right {half_turn_right(z):.3f}")
        if not log_odds or nll < log_odds["nll"]:
            log_odds = {"nll": nll, "decay": decay, **{s: (cues[s]["cues"] / scale) @ w for s in SETS}}
    print(f"chosen decay {log_odds['decay']}")
    net = load_network(args.lines, "UprightLinesNet").eval()
    readings = {s: fused_readings(cache, s, net) for s in SETS}
    for s in SETS:
        fused, thumb = readings[s]
        d = fused[..., 0] - fused[..., 2]
        print(f"{s:9s} upright against upside down, read right: cue {half_turn_right(log_odds[s]):.3f}, thumbnail "
              f"{half_turn_right(thumb[..., 0] - thumb[..., 2]):.3f}, fused {half_turn_right(d):.3f}, "
              f"fused with the cue {half_turn_right(d + log_odds[s]):.3f}")  # fmt: skip
    truth = torch.arange(4)
    nll = {a: float(-with_cue(readings["calibrate"][0], log_odds["calibrate"], a)[:, truth, truth].mean())
           for a in (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0)}  # fmt: skip
    weight = min(nll, key=nll.get)
    print("calibrate NLL of the true turn by the cue's weight: " + ", ".join(f"{a}: {v:.3f}" for a, v in nll.items()))
    for s in SETS:
        report(s, readings[s][0], cues[s]["pitch"], "shipped")
        report(s, with_cue(readings[s][0], log_odds[s], weight), cues[s]["pitch"], f"cue x{weight}")


if __name__ == "__main__":
    main()
