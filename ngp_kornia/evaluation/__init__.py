"""Evaluation of single-image calibration on labelled images.

* :mod:`~ngp_kornia.evaluation.datasets`: :class:`LabelledImage` and its loaders: the York Urban DB with either
  ground-truth horizon (:func:`load_yud`), CSV manifests (:func:`load_manifest`) and folders written by
  ``ngp render`` (:func:`load_renders`).
* :mod:`~ngp_kornia.evaluation.methods`: :class:`Estimate` and the methods (``calibrate()`` under a weights spec, the
  peer lu-vp-detect, a level-horizon baseline), run and timed image by image by :func:`run_interleaved`.
* :mod:`~ngp_kornia.evaluation.lines`: detected segments against hand-labelled ones (:func:`match_segments`).
* :mod:`~ngp_kornia.evaluation.scoring`: :func:`evaluate` (the paper's metrics, horizon AUC) and markdown tables.
* :mod:`~ngp_kornia.evaluation.suite`: the development suite, ``python -m ngp_kornia.evaluation``: every weight set
  over sampling seeds on York Urban (both horizons), CSV manifests and renders, as mean and range.

Usage::

    from ngp_kornia.evaluation import calibrate_method, evaluate, load_manifest, run_interleaved

    images = load_manifest("my_photos/labels.csv")
    runs = run_interleaved({"fsnet": calibrate_method("fsnet")}, images)
    evaluate(images, runs["fsnet"].estimates)["horizon_auc"]
"""

from ngp_kornia.evaluation.datasets import YUD_HORIZONS, LabelledImage, load_manifest, load_renders, load_yud
from ngp_kornia.evaluation.lines import labelled_directions, match_segments
from ngp_kornia.evaluation.methods import (
    Estimate,
    Method,
    MethodRun,
    calibrate_method,
    estimate_from_calibration,
    failed_estimate,
    level_centre,
    lu_vp_detect_method,
    parse_weights_spec,
    run_interleaved,
    weights_and_config,
)
from ngp_kornia.evaluation.scoring import evaluate, kind_table, markdown_table

__all__ = [
    "YUD_HORIZONS",
    "Estimate",
    "LabelledImage",
    "Method",
    "MethodRun",
    "calibrate_method",
    "estimate_from_calibration",
    "evaluate",
    "failed_estimate",
    "kind_table",
    "labelled_directions",
    "level_centre",
    "load_manifest",
    "load_renders",
    "load_yud",
    "lu_vp_detect_method",
    "markdown_table",
    "match_segments",
    "parse_weights_spec",
    "run_interleaved",
    "weights_and_config",
]
