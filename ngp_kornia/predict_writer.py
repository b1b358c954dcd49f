"""How ``ngp predict`` writes its rows from inside Lightning's ``Trainer.predict``: :class:`JsonlWriter`, a
prediction writer on the run folder of :mod:`ngp_kornia.rowfiles`, the handling of Ctrl+C and SIGTERM, and the
progress bar.

Every process appends the rows of its images to its own rows file as soon as they are done; at the end the process
of global rank 0 merges the rows of every process, of this attempt and of the earlier ones of a resumed run, into
``out``. A run stopped early (Ctrl+C, SIGTERM) leaves ``out`` holding the rows finished so far, in input order, and
keeps its run folder, so that ``--resume`` calibrates the rest.
"""

from __future__ import annotations

import json
import os
import secrets
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import lightning as L
from lightning.pytorch.callbacks import BasePredictionWriter, TQDMProgressBar
from lightning.pytorch.callbacks.progress.tqdm_progress import Tqdm

from ngp_kornia.errors import OutputError
from ngp_kornia.rowfiles import RowsFile, RunFolder, count_rows, remove_stale_files

__all__ = ["JsonlWriter", "ProgressBar", "signals_restored", "stop_like_ctrl_c"]


class JsonlWriter(BasePredictionWriter):
    """Writes each batch's rows as soon as they are predicted, to this process's rows file in the run folder of
    ``out``; at the end (and when the run stops early) the process of global rank 0 merges the rows of every
    process and every attempt into ``out``, in input order, each image once.

    In a run of processes forked from the calling one (``ddp_fork``), the calling process only waits: its writer
    never sees a row, and when the run stops early it stops the processes and merges the rows they left.

    Args:
        out: the results file (a link's target: the run folder goes beside the file itself).
        count: the number of images of the run (the rows ``out`` holds at the end).
        state: what the run calibrates, for ``run.json`` (:class:`~ngp_kornia.rowfiles.RunFolder`).
        keep: keep the rows of earlier attempts (a resumed run); else the run folder starts empty.
        world: the number of processes, as far as the calling process knows.

    Attributes:
        images: rows written; in the process that merged, after the run, the rows of ``out``.
        errors: error rows, counted the same way.
        interrupted: the run was stopped (KeyboardInterrupt, SIGTERM or an exception) before every image was done.
        kept: the rows finished before the run stopped are in ``out``.
        incomplete: at the end, rows were missing (:meth:`finish`).
    """

    def __init__(self, out: str | Path, count: int, state: dict, keep: bool = False, world: int = 1) -> None:
        super().__init__(write_interval="batch")
        self.out = Path(out)
        self.folder = RunFolder(self.out)
        self.count, self.state, self.keep = count, state, keep
        self.rank, self.world, self.multi = 0, world, world > 1
        self.attempt: str | None = None
        self.rows: RowsFile | None = None
        self.images = self.errors = 0
        self.interrupted = self.kept = self.incomplete = False

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        """Before the data is shared out: rank 0 makes the run folder ready for this attempt, then every process
        checks that it sees it (a run over several machines needs ``out`` on a file system they share)."""
        self.rank, self.world, self.multi = trainer.global_rank, trainer.world_size, trainer.world_size > 1
        attempt = trainer.strategy.broadcast(secrets.token_hex(4) if trainer.is_global_zero else None)
        problem = None
        if trainer.is_global_zero:
            try:
                remove_stale_files(self.out)
                self.folder.start({**self.state, "attempt": attempt}, keep=self.keep)
            except OSError as err:
                problem = f"cannot write the run folder {self.folder.path}: {err}"
        if not trainer.strategy.reduce_boolean_decision(problem is None, all=True):
            raise OutputError(problem or f"process 0 could not write the run folder {self.folder.path}")
        seen = (self.folder.state() or {}).get("attempt") == attempt
        if not trainer.strategy.reduce_boolean_decision(seen, all=True):
            who = f"process {self.rank}" if not seen else "another process"
            raise OutputError(
                f"{who} does not see the run folder {self.folder.path} that process 0 wrote: the processes of a "
                "run must write to the same folder (a file system every machine shares)"
            )
        self.attempt = attempt

    def on_predict_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        stop_like_ctrl_c()  # in place of Lightning's SIGTERM handler, which lets a prediction run to its end
        self.images = self.errors = 0
        self.interrupted = self.kept = self.incomplete = False
        self.rows = RowsFile(self.folder.rows_file(self.attempt, self.rank))

    def write_on_batch_end(
        self, trainer, pl_module, prediction, batch_indices, batch, batch_idx: int, dataloader_idx: int = 0
    ) -> None:
        lines = (f"{index}\t{json.dumps(row)}\n" for index, row in prediction)
        self.rows.append("".join(lines).encode("utf-8"))
        self.images += len(prediction)
        self.errors += sum("error" in row for _, row in prediction)

    def on_predict_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.close()
        trainer.strategy.barrier("ngp_predict_rows_written")
        if trainer.is_global_zero:
            self.finish()

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        """Stopped early: rank 0 (or the calling process of forked ones) puts the rows finished so far, of every
        attempt, in ``out``, in input order; the run folder stays for ``--resume``."""
        self.close()
        self.interrupted = True
        if self.rank != 0 or self.incomplete:  # incomplete: finish() said out stays as it was
            return
        # the processes forked from this one (not those a launcher script started: they get the signal themselves)
        launched = getattr(trainer.strategy.launcher, "procs", []) if self.multi else []
        processes = [p for p in launched if hasattr(p, "is_alive")]
        _stop(processes)
        _wait_for(processes)
        if self.folder.rows_files():  # none: stopped before any process started writing; out stays as it was
            self.images = self.folder.merge(self.count)
            self.kept = True

    def finish(self) -> None:
        """Every image has its row: merge them into ``out`` and delete the run folder.

        Raises:
            OutputError: rows are missing (a process wrote to a run folder that this one does not see); ``out``
                is unchanged and the rows found stay for ``--resume``.
        """
        written = self.folder.merge(self.count, complete=True)
        if written < self.count:
            self.incomplete = True
            raise OutputError(
                f"only {written} of {self.count} images have a row in {self.folder.path}: the processes of a run "
                f"must write to the same folder (a file system every machine shares); {self.out} is unchanged, "
                "and --resume calibrates the images without a row"
            )
        self.folder.retire()
        self.images, self.errors = count_rows(self.out)
        self.kept = True

    def close(self) -> None:
        """Close this process's rows file, cut back to its last whole row."""
        if self.rows is not None:
            rows, self.rows = self.rows, None
            rows.close()


class ProgressBar(TQDMProgressBar):
    """Lightning's progress bar, on stderr (stdout is for the command's summary): the images (or batches) done of
    this process's share, the rate and the time left. In a run of several processes, process 0 shows its share.

    Args:
        unit: what a step of the bar is, ``"image"`` or ``"batch"``.
    """

    def __init__(self, unit: str = "image") -> None:
        super().__init__()
        self.unit = unit

    @property
    def predict_description(self) -> str:
        world = self.trainer.world_size
        return "ngp predict" if world == 1 else f"ngp predict, process 0 of {world}"

    def init_predict_tqdm(self) -> Tqdm:
        return Tqdm(
            desc=self.predict_description,
            position=2 * self.process_position,
            disable=self.is_disabled,
            leave=True,
            dynamic_ncols=True,
            file=sys.stderr,
            bar_format=self.BAR_FORMAT,
            unit=self.unit,
        )

    def on_predict_batch_start(self, trainer, pl_module, batch, batch_idx: int, dataloader_idx: int = 0) -> None:
        super().on_predict_batch_start(trainer, pl_module, batch, batch_idx, dataloader_idx)
        self.predict_progress_bar.set_description(self.predict_description, refresh=False)  # not "DataLoader 0"


def _stop(processes: list) -> None:
    """Stop the forked processes of a run that ends early (each at its next image, as SIGTERM does there)."""
    for process in processes:
        if process.is_alive() and process.pid is not None:
            try:
                os.kill(process.pid, signal.SIGTERM)
            except ProcessLookupError:  # ended in the meantime
                pass


def _wait_for(processes: list, timeout: float = 30.0) -> None:
    """Let the forked processes of an interrupted run end (each stops at its next image) before their files are read."""
    for process in processes:
        process.join(timeout)


class _StopOnce:
    """A SIGINT / SIGTERM handler that raises KeyboardInterrupt the first time only: a second signal must not cut
    the keeping of the rows short. (Setting the signals to SIG_IGN instead would turn a signal already on its way
    into an OSError, "ignored due to race condition".)"""

    def __init__(self) -> None:
        self.seen = False

    def __call__(self, signum, frame) -> None:
        if not self.seen:
            self.seen = True
            raise KeyboardInterrupt


def stop_like_ctrl_c() -> None:
    """Make SIGINT and SIGTERM raise KeyboardInterrupt once, in this process (from its main thread only)."""
    if threading.current_thread() is threading.main_thread():
        stop = _StopOnce()
        for number in (signal.SIGINT, signal.SIGTERM):
            signal.signal(number, stop)


@contextmanager
def signals_restored() -> Iterator[None]:
    """The caller's SIGINT and SIGTERM handlers back after the block, whatever the run set."""
    saved = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        if threading.current_thread() is threading.main_thread():
            for number, handler in saved.items():
                signal.signal(number, handler)
