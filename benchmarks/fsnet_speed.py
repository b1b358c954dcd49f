"""Speed of the two FSNet variants on this machine: seconds per image to score F frame candidates.

Usage::

    python benchmarks/fsnet_speed.py [--size 224] [--candidates 1 16 64 256] [--runs 15] [--faithful-runs 3]

Each variant is timed in eval mode under ``torch.no_grad`` with the default settings (faithful: ResNet-18 over
17 channels per candidate; shared: a half-width, three-stage ResNet-18 trunk once per image plus a light head per
candidate), after a warm-up call, as the median (and the minimum) of several runs interleaved across the variants,
with torch's thread count as it is (``--threads`` to set it). The time to build the inputs
(:func:`ngp_kornia.nets.fsnet.fsnet_inputs`: resizing, line map, closeness maps) is reported separately.
Multiply-accumulates (GMAC) come from ``torch.utils.flop_counter`` and do not depend on the machine's load, unlike
the times: other jobs may share the CPU, so the load average is printed with them.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from collections.abc import Callable

import torch
from torch.utils.flop_counter import FlopCounterMode

from ngp_kornia.geometry import rotation_from_angles
from ngp_kornia.geometry.frames import FrameCandidates
from ngp_kornia.nets.fsnet import FSNet, FSNetInputs, fsnet_inputs


def interleaved_timings(fns: dict[str, Callable[[], object]], runs: dict[str, int]) -> dict[str, tuple[float, float]]:
    """Median and minimum wall time of each function, after one warm-up call each; the timed calls are interleaved
    round by round, so a burst of load from other jobs hits every function alike."""
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for round_ in range(max(runs.values())):
        for name, fn in fns.items():
            if round_ < runs[name]:
                start = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - start)
    return {name: (statistics.median(t), min(t)) for name, t in times.items()}


def gmac(net: FSNet, inputs: FSNetInputs, num: int) -> float:
    """Multiply-accumulates of scoring ``num`` candidates, in GMAC, from the exact count at 1 and 2 candidates (the
    cost is affine in the candidates)."""

    def count(f: int) -> float:
        with torch.no_grad(), FlopCounterMode(display=False) as counter:
            net(inputs.images, inputs.line_map, inputs.closeness[:, :f], inputs.params[:, :f])
        return counter.get_total_flops() / 2e9

    one, two = count(1), count(2)
    return one + (two - one) * (num - 1)


def synthetic(batch: int, num: int, segments: int, height: int = 480, width: int = 640, seed: int = 0):
    """Random images, segments and frame candidates (the network's cost does not depend on the content)."""
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(batch, 3, height, width, generator=g)
    start = torch.rand(batch, segments, 2, generator=g) * torch.tensor([width - 1.0, height - 1.0])
    offset = torch.randn(batch, segments, 2, generator=g) * 40.0
    segs = torch.stack([start, start + offset], -2)
    mask = torch.ones(batch, segments, dtype=torch.bool)
    angles = (torch.rand(3, batch * num, generator=g) - 0.5) * torch.tensor([[40.0], [20.0], [180.0]])
    R = rotation_from_angles(*angles).reshape(batch, num, 3, 3)
    focal = 0.8 + 2.0 * torch.rand(batch, num, generator=g)
    frames = FrameCandidates(R[..., 1], R[..., 0], focal, R, R.transpose(-1, -2), torch.ones_like(focal) > 0)
    return images, segs, mask, frames


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=224, help="network input side")
    parser.add_argument("--candidates", type=int, nargs="+", default=[1, 16, 64, 256])
    parser.add_argument("--batch", type=int, default=1, help="images per call (times are divided by it)")
    parser.add_argument("--segments", type=int, default=300, help="segments per image for the input maps")
    parser.add_argument("--runs", type=int, default=15, help="timed runs of the shared variant and the inputs")
    parser.add_argument("--faithful-runs", type=int, default=3, help="timed runs of the faithful variant")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's own choice)")
    return parser.parse_args(argv)


def time_candidates(args: argparse.Namespace, nets: dict[str, FSNet]) -> tuple[list[str], dict[int, dict]]:
    """Table rows and timings (median, min) plus GMAC per image for each candidate count."""
    images, segs, mask, frames = synthetic(args.batch, max(args.candidates), args.segments)
    inputs = fsnet_inputs(images, segs, mask, frames, args.size)
    rows, results = [], {}
    with torch.no_grad():
        for num in args.candidates:
            sub = FrameCandidates(*(getattr(frames, k)[:, :num] for k in FrameCandidates.__dataclass_fields__))
            x = FSNetInputs(inputs.images, inputs.line_map, inputs.closeness[:, :num], inputs.params[:, :num])
            fns = {
                "inputs": lambda sub=sub: fsnet_inputs(images, segs, mask, sub, args.size),
                **{name: (lambda net=net, x=x: net(*x)) for name, net in nets.items()},
            }
            runs = {"inputs": args.runs, "shared": args.runs, "faithful": args.faithful_runs}
            row = dict(interleaved_timings(fns, runs))
            for name, net in nets.items():
                row[name + "_gmac"] = gmac(net, x, num) / args.batch
            results[num] = row
            per = {k: (v[0] / args.batch, v[1] / args.batch) for k, v in row.items() if not k.endswith("gmac")}
            rows.append(
                f"| {num} | {per['shared'][0]:.4f} ({per['shared'][1]:.4f}) | "
                f"{per['faithful'][0]:.3f} ({per['faithful'][1]:.3f}) | {per['inputs'][0]:.4f} | "
                f"{row['shared_gmac']:.2f} | {row['faithful_gmac']:.1f} |"
            )
            print(f"  done {num} candidates (load {os.getloadavg()[0]:.2f})", flush=True)
    return rows, results


def print_ratios(results: dict[int, dict]) -> None:
    if 1 in results and 64 in results:
        print(
            f"shared 64 / shared 1: {results[64]['shared'][0] / results[1]['shared'][0]:.2f} (median), "
            f"{results[64]['shared'][1] / results[1]['shared'][1]:.2f} (min), "
            f"{results[64]['shared_gmac'] / results[1]['shared_gmac']:.2f} (GMAC)"
        )
    if 64 in results:
        print(
            f"shared 64 / faithful 64: {results[64]['shared'][0] / results[64]['faithful'][0]:.4f} (median), "
            f"{results[64]['shared'][1] / results[64]['faithful'][1]:.4f} (min), "
            f"{results[64]['shared_gmac'] / results[64]['faithful_gmac']:.4f} (GMAC)"
        )


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.threads is not None:
        torch.set_num_threads(args.threads)

    print(f"# FSNet speed, {args.size}x{args.size} input, batch {args.batch}")
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, {os.cpu_count()} CPUs, "
        f"{platform.processor() or platform.machine()}"
    )
    print(f"load average before: {os.getloadavg()[0]:.2f} (the machine is shared with other jobs: times are noisy)")
    torch.manual_seed(0)
    nets = {
        "shared": FSNet("shared", input_size=args.size).eval(),
        "faithful": FSNet("faithful", input_size=args.size).eval(),
    }
    for name, net in nets.items():
        params = sum(p.numel() for p in net.parameters()) / 1e6
        print(f"{name}: {params:.2f} M parameters, settings {net.settings()}")

    rows, results = time_candidates(args, nets)
    print()
    print("Seconds per image, median (min) of the runs; GMAC per image.")
    print()
    print("| candidates | shared s | faithful s | inputs s | shared GMAC | faithful GMAC |")
    print("|---:|---:|---:|---:|---:|---:|")
    print("\n".join(rows))
    print()
    print_ratios(results)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
