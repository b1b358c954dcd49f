"""The turn of a photo read from its line segments alone, and fused with the orientation network's reading.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/upright_lines_cache.py ... --out lines_cache.pt
    OMP_NUM_THREADS=1 python benchmarks/upright_lines.py --cache lines_cache.pt [--train-sets train[,nyu_train]] \
        [--seed S] [--crop 0.5] [--save S.pt] [--json out.json]
    OMP_NUM_THREADS=1 python benchmarks/upright_lines.py --cache lines_cache.pt --load 0.pt,1.pt,2.pt

Where a photo's segments lie and how they point may tell which way is up (no lines in the sky, verticals converging,
floors against ceilings), cues a 64-pixel thumbnail cannot see. A segment set turned by k quarter turns (as
``np.rot90`` turns an array: counter-clockwise) is read by (a) a length-weighted histogram of positions and directions
with a multinomial logistic regression, (b) a per-segment MLP with masked mean and max pooling. Trained on the
``train`` part of the photo folder (four turns, and their mirror images, which keep up) and NYU-VP 0000-0999;
chosen, and its temperature and the fusion's two weights fitted, on the ``calibrate`` part only. Reported per set:
the share of each photo's four turns read right and the mean NLL of the true turn, paired per photo against the
shipped network (95% bootstrap interval, even / odd halves), as ``benchmarks/upright_views.py`` reports, and the
orientation check's decisions from the shipped and the fused reading (``benchmarks/upright_calibration.py``'s rules).
``--load`` reads with the mean logits of saved readers instead of training one. It imports ``upright_views.py``
and ``upright_calibration.py`` from beside it.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from upright_calibration import decisions
from upright_views import paired, per_photo

from ngp_kornia.nets.upright_lines import UprightLinesNet
from ngp_kornia.nets.weights import save_network
from ngp_kornia.pipeline.segments import pad_segments
from ngp_kornia.training.upright_calibration import fit_temperature
from ngp_kornia.training.upright_lines_fit import fit_fusion


def turn_segments(seg: Tensor, size: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """Segments (B, N, 2, 2) of images of ``size`` (B, 2) (height, width) as they lie in the images turned by k
    quarter turns counter-clockwise (``np.rot90(image, k)``: a pixel (x, y) goes to (y, W - 1 - x)), and the turned
    sizes."""
    for _ in range(k % 4):
        w = size[:, 1].to(seg)[:, None, None]
        seg = torch.stack([seg[..., 1], w - 1 - seg[..., 0]], -1)
        size = size.flip(-1)
    return seg, size


def mirror_segments(seg: Tensor, size: Tensor) -> Tensor:
    """The segments of the images flipped left to right."""
    w = size[:, 1].to(seg)[:, None, None]
    return torch.stack([w - 1 - seg[..., 0], seg[..., 1]], -1)


def crop_segments(seg: Tensor, mask: Tensor, size: Tensor, least: float, gen: torch.Generator) -> tuple:
    """A random window of each image (``least`` to all of its area, aspect changed by up to 4:3): the segments
    clipped to it (Liang-Barsky; those outside masked), in the window's pixels, and the windows' sizes."""
    b = len(seg)
    area = least + (1 - least) * torch.rand(b, generator=gen)
    stretch = torch.exp((torch.rand(b, generator=gen) - 0.5) * 2 * math.log(4 / 3))
    h, w = size[:, 0].float(), size[:, 1].float()
    ch = (h * torch.sqrt(area * stretch)).clamp(max=h).clamp(min=16)
    cw = (w * torch.sqrt(area / stretch)).clamp(max=w).clamp(min=16)
    y0, x0 = (h - ch) * torch.rand(b, generator=gen), (w - cw) * torch.rand(b, generator=gen)
    lo = torch.stack([x0, y0], -1)[:, None]
    hi = torch.stack([x0 + cw - 1, y0 + ch - 1], -1)[:, None]
    p, d = seg[..., 0, :], seg[..., 1, :] - seg[..., 0, :]
    safe = torch.where(d.abs() < 1e-9, torch.full_like(d, 1e-9), d)
    ta, tb = (lo - p) / safe, (hi - p) / safe
    t0 = torch.minimum(ta, tb).amax(-1).clamp(min=0.0)
    t1 = torch.maximum(ta, tb).amin(-1).clamp(max=1.0)
    inside = ((p >= lo) & (p <= hi)) | (d.abs() >= 1e-9)  # an axis the segment does not move along must hold it
    keep = mask & inside.all(-1) & (t1 - t0 > 0) & ((t1 - t0) * d.norm(dim=-1) >= 10.0)
    out = torch.stack([p + t0[..., None] * d, p + t1[..., None] * d], -2) - lo[:, None]
    return torch.where(keep[..., None, None], out, torch.zeros_like(out)), keep, torch.stack([ch, cw], -1).round()


def segment_features(seg: Tensor, size: Tensor) -> Tensor:
    """(B, N, 11) features of segments (B, N, 2, 2) in images of ``size`` (B, 2): midpoint in [-1, 1] on each axis
    (the aspect is not a cue: a turned landscape photo is a portrait one), direction as cos / sin of 2 and 4 times
    its angle, log length over the long side, and against the ray from the centre to the midpoint: cos / sin of twice
    the angle between them (times the distance), the distance and the line's distance from the centre."""
    h, w = size[:, 0].to(seg)[:, None], size[:, 1].to(seg)[:, None]
    long = torch.maximum(h, w)
    mid, d = seg.mean(-2), seg[..., 1, :] - seg[..., 0, :]
    length = d.norm(dim=-1).clamp_min(1e-6)
    ux, uy = d[..., 0] / length, d[..., 1] / length
    c2, s2 = ux * ux - uy * uy, 2 * ux * uy
    mx, my = (mid[..., 0] - (w - 1) / 2) / (w / 2), (mid[..., 1] - (h - 1) / 2) / (h / 2)
    vx, vy = (mid[..., 0] - (w - 1) / 2) / (long / 2), (mid[..., 1] - (h - 1) / 2) / (long / 2)
    r = torch.sqrt(vx * vx + vy * vy + 1e-12)
    rc2, rs2 = (vx * vx - vy * vy) / r, 2 * vx * vy / r  # r cos 2phi, r sin 2phi
    rel_c, rel_s = c2 * rc2 + s2 * rs2, s2 * rc2 - c2 * rs2
    perp = (ux * vy - uy * vx).abs()
    return torch.stack([mx, my, c2, s2, c2 * c2 - s2 * s2, 2 * c2 * s2, torch.log(length / long), rel_c, rel_s, r,
                        perp], -1)  # fmt: skip


def histogram(feats: Tensor, mask: Tensor, cells: int = 4, bins: int = 4) -> Tensor:
    """(B, cells * cells * bins + 1) length-weighted shares of the segments by midpoint cell and direction bin, and
    the log count."""
    length = feats[..., 6].exp() * mask
    cx = ((feats[..., 0] + 1) / 2 * cells).long().clamp(0, cells - 1)
    cy = ((feats[..., 1] + 1) / 2 * cells).long().clamp(0, cells - 1)
    angle = torch.atan2(feats[..., 3], feats[..., 2]) / 2 % math.pi  # [0, pi)
    b = ((angle / math.pi * bins + 0.5).long()) % bins
    idx = (cy * cells + cx) * bins + b
    out = torch.zeros(len(feats), cells * cells * bins).scatter_add_(1, idx, length)
    out = out / out.sum(1, keepdim=True).clamp_min(1e-9)
    return torch.cat([out, torch.log1p(mask.sum(1, keepdim=True).float())], 1)


class SegmentSetReader(nn.Module):
    """Per-segment MLP, length-weighted masked mean and masked max, MLP to four turn logits."""

    def __init__(self, features: int = 11, width: int = 32) -> None:
        super().__init__()
        self.point = nn.Sequential(nn.Linear(features, width), nn.ReLU(), nn.Linear(width, width), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(2 * width, width), nn.ReLU(), nn.Linear(width, 4))

    def forward(self, feats: Tensor, mask: Tensor) -> Tensor:
        e = self.point(feats)
        wgt = feats[..., 6].exp() * mask
        mean = (e * wgt[..., None]).sum(1) / wgt.sum(1, keepdim=True).clamp_min(1e-9)
        mx = e.masked_fill(~mask[..., None], 0.0).amax(1)
        return self.head(torch.cat([mean, mx], -1))


class Ensemble(nn.Module):
    """The mean of several readers' logits."""

    def __init__(self, nets: list[nn.Module]) -> None:
        super().__init__()
        self.nets = nn.ModuleList(nets)

    def forward(self, feats: Tensor, mask: Tensor) -> Tensor:
        return torch.stack([n(feats, mask) for n in self.nets]).mean(0)


def padded(data: dict) -> tuple[Tensor, Tensor, Tensor]:
    seg, mask = pad_segments([torch.from_numpy(s) for s in data["segments"]])
    if seg.shape[1] == 0:
        raise ValueError("no segments in the set")
    return seg.float(), mask, data["size"]


def views(data: dict, mirrors: bool) -> tuple[Tensor, Tensor, Tensor]:
    """Features (P * V, N, 11), mask, turn labels of every turn (and mirror) of every photo of a set, in the order
    photo-major for the four turns (mirrors appended after all unmirrored views)."""
    seg, mask, size = padded(data)
    feats, labels, masks = [], [], []
    for m in (False, True) if mirrors else (False,):
        s0 = mirror_segments(seg, size) if m else seg
        per_turn = [segment_features(*turn_segments(s0, size, k)) for k in range(4)]
        feats.append(torch.stack(per_turn, 1).flatten(0, 1))
        labels.append(torch.arange(4).repeat(len(seg)))
        masks.append(mask.repeat_interleave(4, 0))
    return torch.cat(feats), torch.cat(masks), torch.cat(labels)


def raw_views(data: dict, mirrors: bool) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The turned segments (P * V, N, 2, 2), mask, sizes and labels, in the order of :func:`views`."""
    seg, mask, size = padded(data)
    segs, sizes, masks, labels = [], [], [], []
    for m in (False, True) if mirrors else (False,):
        s0 = mirror_segments(seg, size) if m else seg
        turned = [turn_segments(s0, size, k) for k in range(4)]
        segs.append(torch.stack([t[0] for t in turned], 1).flatten(0, 1))
        sizes.append(torch.stack([t[1] for t in turned], 1).flatten(0, 1))
        masks.append(mask.repeat_interleave(4, 0))
        labels.append(torch.arange(4).repeat(len(seg)))
    return torch.cat(segs), torch.cat(masks), torch.cat(sizes), torch.cat(labels)


def stack_views(parts: list[tuple]) -> tuple:
    """The views of several sets in one batch: each tensor padded along the segments to the longest set."""
    n = max(p[0].shape[1] for p in parts)
    out = []
    for i in range(len(parts[0])):
        pieces = [p[i] for p in parts]
        if pieces[0].dim() > 1:  # (V, N, ...): pad N
            pieces = [F.pad(x, (0, 0) * (x.dim() - 2) + (0, n - x.shape[1])) for x in pieces]
        out.append(torch.cat(pieces))
    return tuple(out)


def fit_logistic(x: Tensor, y: Tensor, decay: float) -> nn.Linear:
    mu, sd = x.mean(0), x.std(0).clamp_min(1e-6)
    lin = nn.Linear(x.shape[1], 4).double()
    xs = ((x - mu) / sd).double()
    opt = torch.optim.LBFGS(lin.parameters(), max_iter=500, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = F.cross_entropy(lin(xs), y) + decay * lin.weight.pow(2).sum()
        loss.backward()
        return loss

    opt.step(closure)
    return lambda z: lin(((z - mu) / sd).double()).float()


def train_mlp(
    train: tuple, cal: tuple, epochs: int, seed: int, width: int = 32, raw: tuple | None = None, crop: float = 1.0
) -> tuple[nn.Module, list]:
    """The reader at the epoch of least calibrate NLL, and the curve. With ``raw`` (segments, mask, size, labels of
    every training view) and ``crop`` < 1, each batch is a random window of its views."""
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    net = SegmentSetReader(width=width)
    opt = torch.optim.AdamW(net.parameters(), lr=3e-3, weight_decay=1e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
    feats, mask, y = train
    best, state, curve = float("inf"), None, []
    for epoch in range(epochs):
        net.train()
        order = torch.randperm(len(y))
        for i in range(0, len(y), 256):
            b = order[i : i + 256]
            if raw is not None and crop < 1.0:
                cs, cm, csz = crop_segments(raw[0][b], raw[1][b], raw[2][b], crop, gen)
                loss = F.cross_entropy(net(segment_features(cs, csz), cm), y[b])
            else:
                loss = F.cross_entropy(net(feats[b], mask[b]), y[b])
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
        net.eval()
        with torch.no_grad():
            val = float(F.cross_entropy(net(cal[0], cal[1]), cal[2]))
            acc = float((net(cal[0], cal[1]).argmax(-1) == cal[2]).float().mean())
        curve.append((epoch, float(loss), val, acc))
        print(f"  epoch {epoch}: train {float(loss):.3f}, calibrate NLL {val:.3f}, right {100 * acc:.1f}%", flush=True)
        if val < best:
            best, state = val, {k: v.clone() for k, v in net.state_dict().items()}
    net.load_state_dict(state)
    return net.eval(), curve


def check_decisions(shipped: Tensor, fused: Tensor, prior: float = 0.75) -> dict:
    """The orientation check's decisions from the reading alone (``benchmarks/upright_calibration.py``: prior 0.75,
    sure 0.9, doubt 0.5), per turn: right or unsure, confidently wrong, doubted."""
    out = {}
    for name, logp in (("shipped", shipped), ("fusion", fused)):
        probs = torch.softmax(logp, -1).reshape(-1, 4)
        rows = decisions(torch.cat([probs, torch.zeros(len(probs), 1)], 1), torch.arange(4).repeat(len(logp)), prior,
                         0.9, 0.5)  # fmt: skip
        out[name] = rows
        print(f"  {name}: right or unsure " + " / ".join(f"{100 * r['right or unsure']:.0f}" for r in rows)
              + "%, confidently wrong " + " / ".join(f"{100 * r['confidently wrong']:.0f}" for r in rows)
              + f"%, upright doubted {100 * rows[0]['doubted']:.1f}%")  # fmt: skip
    return out


def report(name: str, rows: dict, base: tuple) -> dict:
    out = {}
    print(f"\n{name}\n| reading | turn right | NLL | paired turn right | paired NLL |\n|---|---:|---:|---|---|")
    for m, (right, nll) in rows.items():
        a, n = paired(base[0], right), paired(base[1], nll)
        out[m] = {"accuracy": float(right.mean()), "nll": float(nll.mean()), "accuracy vs shipped": a,
                  "nll vs shipped": n}  # fmt: skip
        print(f"| {m} | {100 * right.mean():.1f}% | {nll.mean():.3f} | {100 * a['mean']:+.1f} ({100 * a['lo']:+.1f}.."
              f"{100 * a['hi']:+.1f}; halves {100 * a['even']:+.1f} / {100 * a['odd']:+.1f}) | {n['mean']:+.3f} "
              f"({n['lo']:+.3f}..{n['hi']:+.3f}; halves {n['even']:+.3f} / {n['odd']:+.3f}) |")  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", required=True, help="from benchmarks/upright_lines_cache.py")
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--train-sets", default="train,nyu_train", help="which cached sets to train on")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--crop", type=float, default=1.0, help="train on random windows of this much area or more")
    ap.add_argument("--json")
    ap.add_argument("--save", help="save the chosen MLP reader's state here")
    ap.add_argument("--load", help="comma-separated saved reader states: read by the mean of their logits, no training")
    ap.add_argument("--export", help="with --load: write the readers, their temperature and the fusion weights fitted "
                                     "on the calibrate part as an UprightLinesNet weights file (the shipped one: "
                                     "ngp_kornia/weights/upright_lines.pt)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cache = torch.load(args.cache, weights_only=False)
    start = time.perf_counter()
    names = args.train_sets.split(",")
    train = stack_views([views(cache[s], mirrors=True) for s in names])
    sets = ("calibrate", "test", "yud", "ecd", "nyu_val")
    evals = {s: views(cache[s], mirrors=False) for s in sets}
    print(f"features: {time.perf_counter() - start:.0f} s, {len(train[2])} training views", flush=True)
    readers = {}
    cal = evals["calibrate"]
    if args.load:
        nets = []
        for path in args.load.split(","):
            net = SegmentSetReader(width=args.width)
            net.load_state_dict(torch.load(path))
            nets.append(net.eval())
        mlp = Ensemble(nets)
        with torch.no_grad():
            readers["ensemble"] = (mlp, float(F.cross_entropy(mlp(cal[0], cal[1]), cal[2])))
        choice = evaluate(args, cache, sets, evals, readers, mlp, [])
        if args.export:
            export(nets, choice["ensemble"], args)
        return None
    for decay in (1e-4, 1e-3, 1e-2):
        lr = fit_logistic(histogram(train[0], train[1]), train[2], decay)
        nll = float(F.cross_entropy(lr(histogram(cal[0], cal[1])), cal[2]))
        print(f"histogram + logistic, decay {decay}: calibrate NLL {nll:.3f}")
        readers[f"histogram {decay}"] = (lambda f, m, lr=lr: lr(histogram(f, m)), nll)
    start = time.perf_counter()
    raw = stack_views([raw_views(cache[s], mirrors=True) for s in names]) if args.crop < 1.0 else None
    mlp, curve = train_mlp(train, cal, args.epochs, seed=args.seed, width=args.width, raw=raw, crop=args.crop)
    print(f"MLP trained in {time.perf_counter() - start:.0f} s")
    with torch.no_grad():
        readers["mlp"] = (mlp, float(F.cross_entropy(mlp(cal[0], cal[1]), cal[2])))
    if args.save:
        torch.save(mlp.state_dict(), args.save)
    evaluate(args, cache, sets, evals, readers, mlp, curve)


def evaluate(args, cache, sets, evals, readers, mlp, curve) -> dict:
    out = {"curve": curve, "sets": {}, "choice": {}}
    with torch.no_grad():
        for rname, (reader, _) in readers.items():
            logits = {s: reader(e[0], e[1]).reshape(-1, 4, 4) for s, e in evals.items()}
            t = fit_temperature(logits["calibrate"].reshape(-1, 4), torch.arange(4).repeat(len(logits["calibrate"])))
            lines = {s: torch.log_softmax(lg / t, -1) for s, lg in logits.items()}
            shipped = {s: torch.log_softmax(cache[s]["logits"][..., :4] / cache["temperature"], -1)
                       for s in sets if "logits" in cache[s]}  # fmt: skip
            y = torch.arange(4).repeat(len(lines["calibrate"]))
            u, v = fit_fusion(shipped["calibrate"].reshape(-1, 4), lines["calibrate"].reshape(-1, 4), y)
            print(f"\n### reader {rname}: temperature {t:.2f}, fusion weights shipped {u:.2f}, lines {v:.2f}")
            out["choice"][rname] = {"temperature": t, "fusion": [u, v]}
            for s in sets:
                rows = {"lines": per_photo(lines[s], 1.0)}
                if s in shipped:
                    base = per_photo(shipped[s], 1.0)
                    rows["shipped"] = base
                    rows["fusion"] = per_photo(u * shipped[s] + v * lines[s], 1.0)
                    rows["sum"] = per_photo(shipped[s] + lines[s], 1.0)
                else:
                    base = (torch.full((len(lines[s]),), 0.25, dtype=torch.float64),
                            torch.full((len(lines[s]),), math.log(4), dtype=torch.float64))  # fmt: skip
                out["sets"].setdefault(rname, {})[s] = report(f"{rname} / {s} ({len(lines[s])})", rows, base)
                if s in shipped:
                    out["sets"][rname][s]["decisions"] = check_decisions(shipped[s], u * shipped[s] + v * lines[s])
            out["sets"][rname]["pooled"] = pooled(shipped, {s: u * shipped[s] + v * lines[s] for s in shipped})
        f, m = evals["yud"][0][:1], evals["yud"][1][:1]
        t0 = time.perf_counter()
        for _ in range(200):
            mlp(f, m)
        out["ms_mlp_512"] = (time.perf_counter() - t0) / 200 * 1e3
        print(f"\nMLP reader: {out['ms_mlp_512']:.3f} ms per photo of {int(m.sum())} segments (features cached)")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return out["choice"]


def pooled(shipped: dict, fused: dict) -> dict:
    """The fusion's turn-right gain over the shipped network, paired per photo and pooled over every set with the
    network's reading (the project's rule: the interval, and each set's halves, which :func:`report` prints)."""
    base = torch.cat([per_photo(shipped[s], 1.0)[0] for s in shipped])
    gain = paired(base, torch.cat([per_photo(fused[s], 1.0)[0] for s in shipped]))
    print(f"\npooled over {', '.join(shipped)} ({len(base)} photos): fusion turn right {100 * gain['mean']:+.1f} "
          f"({100 * gain['lo']:+.1f}..{100 * gain['hi']:+.1f})")
    return gain


def export(nets: list[nn.Module], choice: dict, args) -> None:
    """The readers with their temperature and fusion weights as an :class:`UprightLinesNet` weights file."""
    net = UprightLinesNet(width=args.width, members=len(nets))
    for member, reader in zip(net.readers, nets, strict=True):
        member.load_state_dict(reader.state_dict())
    net.temperature.fill_(choice["temperature"])
    net.fusion.copy_(torch.tensor(choice["fusion"]))
    metadata = {"command": "python benchmarks/upright_lines.py --load " + args.load + " --export " + args.export,
                "data": "RealPhotos train part, four turns and mirrors; temperature and fusion fitted on its "
                        "calibrate part", "date": time.strftime("%Y-%m-%d", time.gmtime())}  # fmt: skip
    save_network(net, args.export, net.settings(), metadata)
    print(f"wrote {args.export}")


if __name__ == "__main__":
    main()
