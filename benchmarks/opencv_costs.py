"""Two OpenCV costs of calibrate(path), interleaved image by image over the York Urban half, two passes:

1. line detection (grey conversion + LSD, as calibrate() runs it) with OpenCV on 1 and 2 threads;
2. reading a file: ``np.fromfile`` + ``cv2.imdecode`` + the checks and BGR-to-RGB swap of
   :func:`ngp_kornia.io.read_rgb` (what calibrate() does), against a bare ``cv2.imread`` + ``cv2.cvtColor``.

Usage: python benchmarks/opencv_costs.py /path/to/YorkUrbanDB
"""

import os
import statistics
import sys
import time

import cv2

from ngp_kornia.data.yud import YorkUrbanDB
from ngp_kornia.io import read_rgb
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.pipeline.segments import detect_segments


def _imread(path):
    return cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _report(title, times):
    cells = ", ".join(
        f"{k} {1000 * statistics.fmean(v):.2f} / {1000 * statistics.median(v):.2f}" for k, v in times.items()
    )
    print(f"{title} (mean / median ms): {cells}")


paths = [s.image_path for s in YorkUrbanDB(sys.argv[1], split="train")]
rgbs = [read_rgb(p) for p in paths]
cfg = ParserConfig()
print(f"{len(paths)} images, load {os.getloadavg()[0]:.1f}")
detect = {"1 thread": [], "2 threads": []}
read = {"read_rgb": [], "cv2.imread": []}
detect_segments(rgbs[0], cfg)
for p in range(2):
    for i, (path, rgb) in enumerate(zip(paths, rgbs, strict=True)):
        for n in (1, 2) if (i + p) % 2 else (2, 1):
            cv2.setNumThreads(n)
            start = time.perf_counter()
            detect_segments(rgb, cfg)
            detect["1 thread" if n == 1 else "2 threads"].append(time.perf_counter() - start)
        cv2.setNumThreads(1)
        for name, fn in (("read_rgb", read_rgb), ("cv2.imread", _imread))[:: 1 if (i + p) % 2 else -1]:
            start = time.perf_counter()
            fn(path)
            read[name].append(time.perf_counter() - start)
_report("line detection", detect)
_report("reading", read)
print(f"load after {os.getloadavg()[0]:.1f}")
