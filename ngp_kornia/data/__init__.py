"""Data sets: readers of real benchmarks with ground-truth calibration."""

from ngp_kornia.data.yud import YorkUrbanDB, YUDSample, load_labelled_segments, rotation_from_yud_vps

__all__ = ["YUDSample", "YorkUrbanDB", "load_labelled_segments", "rotation_from_yud_vps"]
