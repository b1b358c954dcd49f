"""The orientation check's rules chosen on real scene photos whose readings are honest.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/upright_scene_rules.py --photos ../shared/data/RealPhotos \\
        --cache lines_cache.pt --init upright_before.pt --thumbs cache --work WORK

The check's temperature, prior and levels were fitted on the photo folder's ``calibrate`` part, four in five of
whose photos are objects and animals that it reads right about half the time; the photos it is for are man-made
scenes, which it reads better. The folder's scene photos (``Urban100/`` and ``SunHays80/``, 180) are read here the
way new photos are: those of the ``train`` part by networks trained without them (four folds: the thumbnail network
fine-tuned from ``--init``, the network the shipped one was fine-tuned from, on the other three folds with renders,
as ``benchmarks/upright_distil.py`` trains without a teacher; the three segment readers as
``benchmarks/upright_lines.py`` trains them), those of the held-back parts by the shipped networks. Each photo in
its four turns is answered by the parser (default weights, seed 0, the check off), and the check's rules are
applied to the readings, the answered pitch and the lines' confidence as ``pipeline/upright_check.py`` applies them.
Truth is the upright answer (none is known): a turned photo is right where it is turned back by its true turn.

Printed: per rule, turned 90 / 180 / 270, the share right or unsure (confidence below 0.2) and the share wrong with
a confidence above 0.5; the upright photos reported turned and doubted; and paired per photo against the shipped
rule (95% bootstrap intervals, even / odd halves of each part): the mean over the three turns of right-or-unsure
minus confidently wrong, and two proper scores of the confidence as the probability of a right answer (Brier and
log loss, the upright turn weighted by the check's prior 0.75, the others by a third of the rest). York Urban and
ECD (``--yud``, ``--manifest`` in the cache) are reported, never chosen on. Every step is kept in ``--work``.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).parent))
import upright_distil as distil  # noqa: E402
from upright_lines import Ensemble, raw_views, train_mlp, views  # noqa: E402

from ngp_kornia import calibrate  # noqa: E402
from ngp_kornia.data.photo_split import split_photos  # noqa: E402
from ngp_kornia.io import read_image_file  # noqa: E402
from ngp_kornia.nets.weights import load_network  # noqa: E402
from ngp_kornia.pipeline.upright_check import fuse_line_reading, weigh_by_pitch, with_prior  # noqa: E402
from ngp_kornia.training.synth.render_config import RenderConfig  # noqa: E402
from ngp_kornia.training.upright_calibration import fit_temperature, turned_logits  # noqa: E402
from ngp_kornia.training.upright_data import STRUCTURELESS_SEEDS, PhotoThumbs, UprightThumbs, sample_keys  # noqa: E402

FOLDS = 4
CHOOSE = ("train", "calibrate", "test")
SHIPPED = {"prior": 0.75, "sure": 0.9, "doubt": 0.5, "power": 1.0}


def fold_of(name: str) -> int:
    """The fold of a photo of the train part, from its path inside the folder (another byte of the split's hash)."""
    return hashlib.sha1(name.encode()).digest()[1] % FOLDS


def is_scene(path: str) -> bool:
    return "Urban100/" in path or "SunHays80/" in path


def subset(data: dict, idx: list[int]) -> dict:
    return {k: ([v[i] for i in idx] if isinstance(v, list) else v[idx]) for k, v in data.items()}


def thumbnail_fold(args: argparse.Namespace, fold: int) -> dict:
    """The thumbnail network fine-tuned without one fold of the train part; its logits of that fold's photos and of
    the calibrate part's, each in four turns (the epoch of least calibrate loss)."""
    hp = argparse.Namespace(renders=3000, repeats=4, lr=5e-4, crop=0.5, teacher_share=0.0, feature_weight=0.0)
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    names = split_photos(args.photos, "train")
    photos = PhotoThumbs(args.photos, names, [f"p{i}" for i in range(len(names))], 128, args.thumbs)
    keys = sample_keys(0, STRUCTURELESS_SEEDS["train"], hp.renders, 6)
    renders = UprightThumbs(keys, 128, RenderConfig(foliage=0.5), args.thumbs)
    photos.prepare(0), renders.prepare(0)
    kept = torch.tensor([i for i, n in enumerate(names) if fold_of(n) != fold])
    thumbs, rthumbs = distil.thumbs_of(photos)[kept], distil.thumbs_of(renders)
    structured, posts = torch.tensor([k[0] == "r" for k in keys]), torch.full((len(kept), 4, 4), 0.25)
    net = load_network(args.init, "UprightNet")
    opt = torch.optim.Adam(net.parameters(), lr=hp.lr)
    sched = torch.optim.lr_scheduler.StepLR(opt, 4, 0.5)
    cal, best = split_photos(args.photos, "calibrate"), (float("inf"), None)
    for _ in range(8):
        distil.epoch(net, opt, thumbs, posts, rthumbs, structured, hp, gen)
        sched.step()
        net.eval()
        with torch.no_grad():
            logits, turns = turned_logits(net, args.photos, cal)
        loss = float(F.cross_entropy(logits[:, :4], turns))
        best = (loss, {k: v.clone() for k, v in net.state_dict().items()}) if loss < best[0] else best
    net.load_state_dict(best[1])
    held = [n for n in names if fold_of(n) == fold and is_scene(n)]
    with torch.no_grad():
        return {"names": held, "logits": turned_logits(net, args.photos, held)[0],
                "cal": turned_logits(net, args.photos, cal)}  # fmt: skip


def lines_fold(cache: dict, fold: int, root: str) -> tuple[Ensemble, float]:
    """Three segment readers (seeds 0-2) trained without one fold of the train part, their temperature fitted on
    the calibrate part."""
    kept = [i for i, n in enumerate(cache["train"]["names"]) if fold_of(str(n).replace(root, "")) != fold]
    train, cal = views(subset(cache["train"], kept), mirrors=True), views(cache["calibrate"], mirrors=False)
    nets = [train_mlp(train, cal, 30, seed=s, width=32)[0].eval() for s in range(3)]
    ens = Ensemble(nets)
    with torch.no_grad():
        return ens, fit_temperature(ens(cal[0], cal[1]), cal[2])


def readings_train(args: argparse.Namespace, cache: dict) -> dict:
    """Out-of-fold (P, 4, 5) thumbnail and (P, 4, 4) segment log-probabilities of the train part's scene photos."""
    root = str(Path(args.photos)) + "/"
    names, thumbs, lines = [], [], []
    for fold in range(FOLDS):
        path = Path(args.work) / f"thumbnail_fold{fold}.pt"
        if not path.exists():
            start = time.perf_counter()
            torch.save(thumbnail_fold(args, fold), path)
            print(f"thumbnail network without fold {fold}: {time.perf_counter() - start:.0f} s", flush=True)
        out = torch.load(path, weights_only=False)
        temperature = fit_temperature(out["cal"][0][:, :4], out["cal"][1])
        ens, lines_t = lines_fold(cache, fold, root)
        idx = [i for i, n in enumerate(cache["train"]["names"]) if str(n).replace(root, "") in set(out["names"])]
        order = {n: k for k, n in enumerate(out["names"])}
        with torch.no_grad():
            read = ens(*views(subset(cache["train"], idx), mirrors=False)[:2]).reshape(-1, 4, 4)
        for j, i in enumerate(idx):
            k = order[str(cache["train"]["names"][i]).replace(root, "")]
            names.append(str(cache["train"]["names"][i]))
            thumbs.append(torch.log_softmax(out["logits"][4 * k : 4 * k + 4] / temperature, -1))
            lines.append(torch.log_softmax(read[j] / lines_t, -1))
    return {"names": names, "thumb": torch.stack(thumbs).double(), "lines": torch.stack(lines).double()}


def readings_shipped(cache: dict, part: str, lines_net) -> dict:
    """The shipped networks' readings of a part's scene photos (every photo of York Urban and ECD)."""
    idx = [i for i, n in enumerate(cache[part]["names"]) if part in ("yud", "ecd") or is_scene(str(n))]
    data = subset(cache[part], idx)
    seg, mask, size, _ = raw_views(data, False)
    with torch.no_grad():
        lines = torch.cat([lines_net(seg[i : i + 1], mask[i : i + 1], int(size[i, 0]), int(size[i, 1]))
                           for i in range(len(seg))])  # fmt: skip
    return {"names": [str(n) for n in data["names"]], "lines": lines.reshape(-1, 4, 4).double(),
            "thumb": torch.log_softmax(data["logits"] / cache["temperature"], -1).double()}  # fmt: skip


def answers(names: list[str]) -> dict:
    """The parser's answered pitch and confidence (P, 4) of every photo in its four turns, the check off."""
    pitch, conf = [], []
    for path in names:
        rgb = read_image_file(path)
        outs = [calibrate(np.ascontiguousarray(np.rot90(rgb, k)), "default", seed=0, config={"upright.enabled": False})
                for k in range(4)]  # fmt: skip
        pitch.append([float(o.pitch) for o in outs])
        conf.append([float(o.confidence) for o in outs])
    return {"pitch": torch.tensor(pitch, dtype=torch.float64), "conf": torch.tensor(conf, dtype=torch.float64)}


def gather(args: argparse.Namespace) -> dict:
    """Every set's readings and answers, kept in ``--work``."""
    path = Path(args.work) / "sets.pt"
    if path.exists():
        return torch.load(path, weights_only=False)
    cache = torch.load(args.cache, weights_only=False)
    lines_net = load_network(args.lines, "UprightLinesNet").eval()
    sets = {"train": readings_train(args, cache)}
    for part in ("calibrate", "test", "yud", "ecd"):
        sets[part] = readings_shipped(cache, part, lines_net)
    for name, data in sets.items():
        start = time.perf_counter()
        data.update(answers(data["names"]))
        print(f"{name}: {len(data['names'])} photos answered in four turns in {time.perf_counter() - start:.0f} s")
    torch.save(sets, path)
    return sets


def fused(data: dict, lines_net) -> torch.Tensor:
    """(P * 4, 5) probabilities: the thumbnail's four turns fused with the segments' as the parser fuses them."""
    return fuse_line_reading(lines_net, data["thumb"].exp().reshape(-1, 5), data["lines"].reshape(-1, 4))


def decide(data: dict, rule: dict, lines_net) -> dict:
    """Per photo and turn (P * 4,): the true turn, whether the answer is right, and its confidence, by the rules of
    ``pipeline/upright_check.py`` with ``rule``'s prior, sure, doubt and power."""
    probs = weigh_by_pitch(with_prior(fused(data, lines_net), rule["prior"]), data["pitch"].reshape(-1), 15.0)
    upright, (likeliest, turns) = probs[:, 0], probs[:, :4].max(-1)
    valid = probs[:, 4] < likeliest
    reported = (turns > 0) & (likeliest >= rule["sure"]) & valid
    factor = torch.where(reported, likeliest, (upright / rule["doubt"]).clamp(max=1.0) ** rule["power"])
    truth = torch.arange(4).repeat(len(data["names"]))
    return {"truth": truth, "right": torch.where(reported, turns, 0) == truth, "reported": reported,
            "doubted": upright < rule["doubt"], "lines": data["conf"].reshape(-1),
            "confidence": torch.where(valid, data["conf"].reshape(-1) * factor, 0.0)}  # fmt: skip


def per_photo(d: dict) -> dict:
    """(P,) per photo: the mean over the three turns of right-or-unsure minus confidently wrong, and the Brier score
    and log loss of the confidence against the lines' own where right (0 where wrong), the upright turn weighted by
    the prior."""
    good = (d["right"] | (d["confidence"] < 0.2)).double() - (~d["right"] & (d["confidence"] > 0.5)).double()
    target = torch.where(d["right"], d["lines"], 0.0)
    p = d["confidence"].clamp(1e-4, 1 - 1e-4)
    weight = torch.where(d["truth"] == 0, 0.75, 0.25 / 3)
    brier = ((d["confidence"] - target) ** 2 * weight).reshape(-1, 4).sum(1)
    loss = (-(target * p.log() + (1 - target) * (1 - p).log()) * weight).reshape(-1, 4).sum(1)
    return {"target": good.reshape(-1, 4)[:, 1:].mean(1), "brier": brier, "log loss": loss}


def summary(d: dict) -> str:
    turns = [d["truth"] == k for k in range(4)]
    rou = [float((d["right"] | (d["confidence"] < 0.2))[t].double().mean()) for t in turns[1:]]
    wrong = [float((~d["right"] & (d["confidence"] > 0.5))[t].double().mean()) for t in turns[1:]]
    return (f"right or unsure {' / '.join(f'{100 * v:.0f}' for v in rou)}%, confidently wrong "
            f"{' / '.join(f'{100 * v:.0f}' for v in wrong)}%; upright reported turned "
            f"{100 * float(d['reported'][turns[0]].double().mean()):.1f}%, doubted "
            f"{100 * float(d['doubted'][turns[0]].double().mean()):.1f}%")  # fmt: skip


def interval(x: torch.Tensor, draws: int = 4000) -> str:
    idx = torch.randint(0, len(x), (draws, len(x)), generator=torch.Generator().manual_seed(0))
    means = x[idx].mean(1)
    return f"{float(x.mean()):+.4f} ({float(means.quantile(0.025)):+.4f}..{float(means.quantile(0.975)):+.4f})"


def compare(sets: dict, names: tuple, rule: dict, lines_net) -> str:
    """The rule against the shipped one, paired per photo, pooled over ``names``, with each part's halves."""
    diffs, halves = {}, []
    for name in names:
        a, b = per_photo(decide(sets[name], SHIPPED, lines_net)), per_photo(decide(sets[name], rule, lines_net))
        for key in a:
            diffs.setdefault(key, []).append(b[key] - a[key])
        t = b["target"] - a["target"]
        halves.append(f"{name} {100 * float(t[0::2].mean()):+.1f} / {100 * float(t[1::2].mean()):+.1f}")
    out = {k: torch.cat(v) for k, v in diffs.items()}
    return (
        f"target {interval(out['target'])}, halves {'; '.join(halves)}; Brier {interval(out['brier'])}; "
        f"log loss {interval(out['log loss'])}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photos", required=True, help="the folder of upright photos")
    ap.add_argument("--cache", required=True, help="benchmarks/upright_lines_cache.py's output")
    ap.add_argument("--init", required=True, help="the thumbnail network to fine-tune per fold")
    ap.add_argument("--thumbs", default="cache", help="the training thumbnails' cache folder")
    ap.add_argument("--lines", default="ngp_kornia/weights/upright_lines.pt", help="the shipped segment reader")
    ap.add_argument("--work", required=True, help="a folder for every step's results")
    ap.add_argument("--powers", default="1.5,2,3,4", help="the doubt powers to compare with the shipped 1")
    args = ap.parse_args()
    torch.set_num_threads(1)
    Path(args.work).mkdir(parents=True, exist_ok=True)
    sets = gather(args)
    lines_net = load_network(args.lines, "UprightLinesNet").eval()
    for power in [1.0, *(float(p) for p in args.powers.split(","))]:
        rule = {**SHIPPED, "power": power}
        print(f"\ndoubt power {power}")
        for name in sets:
            print(f"  {name:9s} {summary(decide(sets[name], rule, lines_net))}")
        if power != 1.0:
            print(f"  paired, the chooser (train, calibrate, test): {compare(sets, CHOOSE, rule, lines_net)}")
            for name in ("yud", "ecd"):
                print(f"  paired, {name}: {compare(sets, (name,), rule, lines_net)}")


if __name__ == "__main__":
    main()
