"""Line detection time (grey conversion + LSD, as calibrate() runs it) with OpenCV on 1 and 2 threads,
interleaved image by image over the York Urban half, two passes.

Usage: python benchmarks/opencv_threads.py /path/to/YorkUrbanDB
"""
import os
import statistics
import sys
import time

import cv2

from ngp_kornia.api import segments_of_rgb
from ngp_kornia.data.yud import YorkUrbanDB
from ngp_kornia.io import read_rgb
from ngp_kornia.models import ParserConfig

rgbs = [read_rgb(s.image_path) for s in YorkUrbanDB(sys.argv[1], split="train")]
cfg = ParserConfig()
t = {1: [], 2: []}
segments_of_rgb(rgbs[0], cfg)
for p in range(2):
    for i, rgb in enumerate(rgbs):
        for n in ((1, 2) if (i + p) % 2 else (2, 1)):
            cv2.setNumThreads(n)
            start = time.perf_counter()
            segments_of_rgb(rgb, cfg)
            t[n].append(time.perf_counter() - start)
print(f"load {os.getloadavg()[0]:.1f}; mean / median ms: " + ", ".join(
    f"{n} thread(s) {1000*statistics.fmean(v):.1f} / {1000*statistics.median(v):.1f}" for n, v in t.items()))
