"""Training curves: read what a Lightning logger wrote (``CSVLogger``'s ``metrics.csv`` or ``TensorBoardLogger``'s
event files) and plot the loss and every validation metric against the training step, with labelled axes.

``ngp-train plot LOGDIR -o curves.png`` calls :func:`read_metrics` and :func:`plot_curves`. Plotting needs
matplotlib (``pip install 'ngp-kornia[plot]'``); reading TensorBoard files needs tensorboard (``[tensorboard]``).
"""

from __future__ import annotations

import csv
from pathlib import Path

__all__ = ["find_log", "metric_label", "plot_curves", "read_metrics"]

#: y-axis labels of the metrics the LightningModules log, by name without the ``train/`` / ``val/`` prefix
_LABELS = {
    "loss": "loss",
    "zenith_error": "zenith error (degrees)",
    "horizon_error": "horizon error (fraction of image height)",
    "horizon_auc": "horizon AUC on [0, 0.25]",
    "accuracy": "accuracy (fraction of frames)",
    "positive_rate": "positive labels (fraction of frames)",
}
_Series = list[tuple[int, float]]


def find_log(path: str | Path) -> Path:
    """The newest ``metrics.csv`` or TensorBoard event file at or under ``path``.

    Raises:
        FileNotFoundError: nothing a logger wrote is there; the message names the folder.
    """
    path = Path(path)
    if path.is_file():
        return path
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such folder; give the logger's folder (e.g. runs/zsnet)")
    found = [*path.rglob("metrics.csv"), *path.rglob("events.out.tfevents.*")]
    if not found:
        raise FileNotFoundError(
            f"{path}: no metrics.csv (CSVLogger) or events.out.tfevents.* (TensorBoardLogger) under this folder"
        )
    return max(found, key=lambda p: (p.stat().st_mtime_ns, str(p)))


def read_metrics(path: str | Path) -> dict[str, _Series]:
    """Logged scalars as ``{name: [(step, value), ...]}``, from a ``metrics.csv`` or a TensorBoard event file (or
    the newest one under a folder, see :func:`find_log`)."""
    log = find_log(path)
    if log.name == "metrics.csv":
        series: dict[str, _Series] = {}
        with open(log, newline="") as f:
            for row in csv.DictReader(f):
                for key, value in row.items():
                    if key not in ("step", "epoch") and value not in ("", None):
                        series.setdefault(key, []).append((int(row["step"]), float(value)))
        return series
    try:
        from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    except ImportError as err:
        raise ImportError(f"{log} is a TensorBoard file: pip install 'ngp-kornia[tensorboard]' to read it") from err
    events = EventAccumulator(str(log), size_guidance={"scalars": 0})
    events.Reload()
    tags = [t for t in events.Tags()["scalars"] if t != "epoch"]
    return {t: [(int(e.step), float(e.value)) for e in events.Scalars(t)] for t in tags}


def metric_label(name: str) -> str:
    """The y-axis label of a metric (``val/zenith_error`` -> ``zenith error (degrees)``)."""
    base = name.split("/", 1)[-1]
    for key in sorted(_LABELS, key=len, reverse=True):
        if base == key or base.startswith(key + "_"):
            return _LABELS[key]
    return base.replace("_", " ")


def _panels(metrics: dict[str, _Series]) -> dict[str, list[str]]:
    """The metrics drawn together: the losses in one panel, each other validation metric with its variants
    (``val/zenith_error`` with ``val/zenith_error_uniform``)."""
    panels: dict[str, list[str]] = {}
    losses = [n for n in ("train/loss", "val/loss") if n in metrics]
    if losses:
        panels["loss"] = losses
    names = sorted(n for n in metrics if n.startswith("val/") and not n.split("/", 1)[1].startswith("loss"))
    for name in names:
        base = next((m for m in names if name != m and name.startswith(m + "_")), name)
        panels.setdefault(base.split("/", 1)[1], []).append(name)
    return panels


def plot_curves(metrics: dict[str, _Series], out: str | Path | None = None, title: str | None = None):
    """Plot the training loss and the validation metrics against the training step.

    A metric's variants (``val/zenith_error_uniform`` beside ``val/zenith_error``: the baselines the modules log)
    are drawn grey and dashed in its panel.

    Args:
        metrics: ``{name: [(step, value), ...]}``, as :func:`read_metrics` returns.
        out: PNG (or any format matplotlib writes) to save, or None.
        title: title over the panels.

    Returns:
        the matplotlib ``Figure``: one panel for the losses, one per validation metric with its variants, each
        with the x axis "training step" and the metric's unit on the y axis.

    Raises:
        ValueError: no loss or validation metric to plot.
        ImportError: matplotlib is missing (``pip install 'ngp-kornia[plot]'``).
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as err:
        raise ImportError("plotting needs matplotlib: pip install 'ngp-kornia[plot]'") from err
    panels = _panels(metrics)
    if not panels:
        raise ValueError(f"nothing to plot: no train/loss or val/ metric among {sorted(metrics)}")
    cols = min(len(panels), 3)
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.4 * rows), squeeze=False)
    for ax, (name, members) in zip(axes.flat, panels.items(), strict=False):
        for i, member in enumerate(members):
            steps, values = zip(*metrics[member], strict=True)
            dense = len(steps) > 30
            style = {"color": "0.5", "linestyle": "--"} if i and name != "loss" else {}  # a baseline variant: grey
            ax.plot(steps, values, marker=None if dense else "o", markersize=3, linewidth=1 if dense else 1.5,
                    label=member, **style)
        ax.set_xlabel("training step")
        ax.set_ylabel(metric_label(members[0]))
        ax.set_title(name.replace("_", " "))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for ax in list(axes.flat)[len(panels):]:
        ax.remove()
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=110)
    return fig
