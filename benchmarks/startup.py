"""Start-up time of the command line: wall seconds of ``ngp --version``, ``ngp calibrate --help``, ``ngp-train
--help`` and a wrong argument, next to ``python -c pass`` (an interpreter that imports nothing) in the same run.

Usage::

    python benchmarks/startup.py [--runs 5]

Each command runs in a fresh interpreter through the console entry points (``ngp_kornia._launch``), the commands
interleaved run by run so that a change in the machine's load falls on all of them; the median and the minimum of
the runs are printed with the ratio of the medians to ``python -c pass``. Other jobs may share the CPU: the load
average is printed with the times.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

ENTRY = "import sys; from ngp_kornia._launch import {entry}; sys.argv[0] = '{name}'; sys.exit({entry}())"
COMMANDS = {
    "python -c pass": ["-c", "pass"],
    "ngp --version": ["-c", ENTRY.format(entry="ngp", name="ngp"), "--version"],
    "ngp calibrate --help": ["-c", ENTRY.format(entry="ngp", name="ngp"), "calibrate", "--help"],
    "ngp calibrate missing.jpg": ["-c", ENTRY.format(entry="ngp", name="ngp"), "calibrate", "missing.jpg"],
    "ngp-train --help": ["-c", ENTRY.format(entry="ngp_train", name="ngp-train"), "--help"],
}


def time_once(args: list[str], cwd: str) -> float:
    """Wall seconds of one run of ``python ARGS``."""
    start = time.perf_counter()
    subprocess.run([sys.executable, *args], cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="runs of each command (the median is reported)")
    runs = parser.parse_args().runs
    times: dict[str, list[float]] = {name: [] for name in COMMANDS}
    with tempfile.TemporaryDirectory() as cwd:  # an empty folder: missing.jpg is missing
        for _ in range(runs):
            for name, args in COMMANDS.items():
                times[name].append(time_once(args, cwd))
    print(f"load average {os.getloadavg()[0]:.2f}, {runs} runs each, Python {sys.version.split()[0]}")
    base = statistics.median(times["python -c pass"])
    for name, values in times.items():
        median = statistics.median(values)
        print(f"{name:28} median {median:.3f} s  min {min(values):.3f} s  {median / base:5.2f}x python -c pass")


if __name__ == "__main__":
    main()
