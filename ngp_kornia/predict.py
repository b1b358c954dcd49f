"""Calibrating a whole folder with Lightning's ``Trainer.predict``, one JSON line per image, in one or several
processes (``ngp predict FOLDER --out results.jsonl --devices N``).

Rows are written as batches finish and nothing is kept in memory, so a folder of any size can be processed. They go
to a hidden temporary file beside ``out`` (``.<out name>.<run id>.tmp``) that is renamed to ``out`` at the end, so
``out`` is never half-written. With several processes (forked from this one; DDP on the CPU, gloo backend) each
rank writes its own part file ``.<out name>.<run id>.part<R>`` holding ``<dataset index>\\t<json>`` lines; after a
barrier rank 0 merges the parts in dataset order, keeping each index once, and deletes them (the run id is drawn
per run, so no other file is ever touched). An ``out`` that is one of the input images is refused.

Every image is isolated: any exception while reading or calibrating it becomes its error row, never the end of the
run. An interrupted run (Ctrl+C, SIGINT, or SIGTERM as ``kill`` and service managers send) still leaves ``out``
holding the rows of the images finished so far, in folder order, and the run reports it; it does not resume:
running the command again starts over. A run stopped by an error (a full disk, a file-size limit) keeps them the
same way when it can, and removes its hidden files whatever happens. A process killed outright (SIGKILL) cannot
clean up: the next run for the same ``out`` deletes the hidden files of runs that are gone (each run holds a lock on
the files it writes, so a run still going is told apart; without ``fcntl``, on Windows, they are left).

Every image is calibrated on its own, exactly as :func:`ngp_kornia.calibrate` does for a file (LSD on the decoded
8-bit image, the candidate sampling seeded per image), so a row equals what ``ngp calibrate`` prints for that file.
"""

from __future__ import annotations

import json
import os
import secrets
import signal
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from torch import Tensor
from torch.multiprocessing.spawn import ProcessException
from torch.utils.data import DataLoader

try:  # an optional dependency: calibrate() and the rest of the core run without it
    import lightning as L
    from lightning.pytorch.callbacks import BasePredictionWriter
except ImportError as err:
    raise ImportError(
        f"folder prediction needs Lightning ({err}); install it with: pip install 'ngp-kornia[train]'"
    ) from err

from ngp_kornia.api import file_priors, load_parser, shared_focal, with_orientation
from ngp_kornia.data.folder import ImageFolder
from ngp_kornia.errors import NGPWarning, OutputError
from ngp_kornia.folder_items import FolderImages, FolderItem, collate_items, error_reason
from ngp_kornia.pipeline import Calibration, NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.priors import Priors, checked_seed
from ngp_kornia.pipeline.segments import line_workers
from ngp_kornia.pipeline.shared_camera import SharedFocal, not_shared_folders, with_shared_focal
from ngp_kornia.preflight import check_folder, same_file
from ngp_kornia.rowfiles import count_rows, merge_parts, open_locked, remove_stale_files
from ngp_kornia.rows import result_row
from ngp_kornia.threads import pipeline_threads, usable_cores

__all__ = [
    "FolderPredictor",
    "JsonlWriter",
    "cap_devices",
    "folder_cameras",
    "merge_parts",
    "predict_folder",
    "remove_stale_files",
    "usable_cores",
]


class FolderPredictor(L.LightningModule):
    """The parser as a LightningModule whose ``predict_step`` turns a batch of :class:`FolderItem` into
    ``(index, row)`` pairs, ``row`` being :func:`~ngp_kornia.rows.result_row` (``ngp calibrate --json``'s) or
    ``{"image": name, "error": reason}``.

    Args:
        parser: the pipeline (see :func:`ngp_kornia.api.load_parser`).
        root: the folder the item names are relative to; with ``exif`` the files' EXIF focal lengths are read
            from there.
        seed: the sampling seed of every image.
        priors: what is known of every image's camera.
        exif: take each file's EXIF focal length where ``priors`` gives none (:func:`ngp_kornia.api.file_priors`).
        cameras: per sub-folder (its path relative to ``root``, ``"."`` for ``root``), the focal length its photos
            share (``--same-camera``); None: each photo its own.
    """

    def __init__(
        self,
        parser: NeuralGeometricParser,
        root: str | Path | None = None,
        seed: int = 0,
        priors: Priors | None = None,
        exif: bool = False,
        cameras: dict[str, SharedFocal] | None = None,
    ) -> None:
        super().__init__()
        self.parser = parser
        self.root = None if root is None else Path(root)
        self.seed, self.priors, self.exif = checked_seed(seed), priors or Priors(), exif
        self.cameras = cameras

    def calibrate(
        self, image: Tensor, name: str | None = None, segments: Tensor | None = None, mask: Tensor | None = None
    ) -> Calibration:
        """Calibrate one (3, H, W) image as :func:`ngp_kornia.calibrate` does for a file (``name``, relative to
        ``root``, is where an EXIF focal length is read from; ``segments`` (1, N, 2, 2) and ``mask`` (1, N): its
        lines when already detected)."""
        priors = self.priors
        if name is not None and self.root is not None:  # the image's own prior, where its file records one
            priors = file_priors(self.root / name, image.shape[-2], image.shape[-1], priors, self.exif)
        # the parser detects lines on the image rounded to 8 bits, which are the exact pixels the file decoded to
        # (the float image is uint8 / 255): the same lines, hence the same answer, as calibrate() on the file
        if segments is not None:
            segments, mask = segments.to(self.device), mask.to(self.device)
        shared = None if self.cameras is None or name is None else self.cameras.get(Path(name).parent.as_posix())
        if shared is not None:  # the focal length of the photo's folder, estimated from all of them
            priors = priors.with_focal(shared.focal)
        result = self.parser(image[None].to(self.device), segments, mask, seed=self.seed, priors=priors)[0]
        return result if shared is None else with_shared_focal(result, shared)

    def predict_step(self, batch: list[FolderItem], batch_idx: int) -> list[tuple[int, dict]]:
        rows = []
        for item in batch:  # one by one: the seeded sampling then gives calibrate()'s answer for every image
            if item.error is not None:
                rows.append((item.index, {"image": item.name, "error": item.error}))
                continue
            try:
                result = self.calibrate(item.image, item.name, item.segments, item.mask)
                if item.orientation is not None:
                    result = with_orientation(result, item.orientation)
                rows.append((item.index, result_row(item.name, result)))
            except Exception as err:  # one image's failure is its row, never the end of the run
                rows.append((item.index, {"image": item.name, "error": error_reason(err, item.name)}))
        return rows


class JsonlWriter(BasePredictionWriter):
    """Writes each batch's rows as soon as it is predicted: to a temporary file beside ``out`` in a single process,
    to a part file per rank (lines ``<index>\\t<json>``) in a multi-process run, which rank 0 merges; the result
    is renamed to ``out`` at the end, or when the run is interrupted or fails (then holding the images finished so
    far, cut back to whole rows). Each file is locked while it is written (see :func:`remove_stale_files`).

    In a multi-process run the processes are forked from the calling one, which only waits for them: its writer
    never sees a row, and when the run stops early it stops the processes and merges the part files they left.

    Attributes:
        images: rows written; in the calling process of a multi-process run, after it, the rows of the merged file.
        errors: error rows, counted the same way.
        interrupted: the run was stopped (KeyboardInterrupt, SIGTERM or an exception) before every image was done.
        kept: the rows finished before the run stopped are in ``out``.
    """

    def __init__(self, out: str | Path, world: int = 1) -> None:
        super().__init__(write_interval="batch")
        self.out = Path(out)
        self.file: IO[bytes] | None = None
        self.multi = world > 1
        self.rank, self.world = 0, world
        self.run_id = secrets.token_hex(4)  # made before the fork, so every process names the same files
        self.images = self.errors = self.whole = 0  # whole: bytes of the file up to its last complete row
        self.interrupted = self.kept = False

    def part(self, rank: int) -> Path:
        """The part file of a rank (hidden, named by this run's id so no other file is ever touched)."""
        return self.out.with_name(f".{self.out.name}.{self.run_id}.part{rank}")

    @property
    def temporary(self) -> Path:
        """The file the rows go to before it is renamed to ``out``."""
        return self.out.with_name(f".{self.out.name}.{self.run_id}.tmp")

    def on_predict_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        _stop_like_ctrl_c()  # in place of Lightning's SIGTERM handler, which lets a prediction run to its end
        self.multi = trainer.world_size > 1
        self.rank, self.world = trainer.global_rank, trainer.world_size
        self.images = self.errors = self.whole = 0
        self.interrupted = self.kept = False
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self.file = open_locked(self.part(self.rank) if self.multi else self.temporary)

    def write_on_batch_end(
        self, trainer, pl_module, prediction, batch_indices, batch, batch_idx: int, dataloader_idx: int = 0
    ) -> None:
        lines = (json.dumps(row) for _, row in prediction)
        if self.multi:
            lines = (f"{index}\t{line}" for (index, _), line in zip(prediction, lines, strict=True))
        data = "".join(line + "\n" for line in lines).encode("utf-8")
        self.file.write(data)
        self.file.flush()  # rows survive an interruption or a crash later in the run
        self.whole += len(data)
        self.images += len(prediction)
        self.errors += sum("error" in row for _, row in prediction)

    def on_predict_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.close()
        if not self.multi:
            self.temporary.replace(self.out)
            return
        trainer.strategy.barrier("ngp_predict_parts_written")
        if trainer.is_global_zero:
            self.finish()  # the calling process counts the merged rows

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        """Stopped early: the main process keeps the rows finished so far, in folder order, as ``out``."""
        self.close()
        self.interrupted = True
        if self.rank != 0:
            return
        if self.multi:
            processes = getattr(trainer.strategy.launcher, "procs", [])
            _stop(processes)
            _wait_for(processes)
            self.images = self.finish()
        elif self.temporary.exists():
            self.temporary.replace(self.out)
            self.kept = True

    def finish(self) -> int:
        """Merge the part files that exist into ``out`` (through the temporary file), delete them; rows written.
        The part files and the temporary file are deleted even when the merge fails (a full disk)."""
        parts = [p for p in (self.part(rank) for rank in range(self.world)) if p.exists()]
        try:
            written = merge_parts(parts, self.temporary)
            self.temporary.replace(self.out)
            self.kept = True
        finally:
            for path in (*parts, self.temporary):
                path.unlink(missing_ok=True)
        return written

    def close(self) -> None:
        """Close the file and cut it back to its last complete row: a write that failed (a full disk) or was
        interrupted may have left part of one."""
        if self.file is None:
            return
        file, self.file = self.file, None
        try:
            file.close()
        except OSError:  # the flush of rows that did not fit; the file is closed all the same
            pass
        os.truncate(file.name, self.whole)


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


def _stop_like_ctrl_c() -> None:
    """Make SIGINT and SIGTERM raise KeyboardInterrupt once, in this process (from its main thread only)."""
    if threading.current_thread() is threading.main_thread():
        stop = _StopOnce()
        for number in (signal.SIGINT, signal.SIGTERM):
            signal.signal(number, stop)


@contextmanager
def _signals_restored() -> Iterator[None]:
    """The caller's SIGINT and SIGTERM handlers back after the block, whatever the run set."""
    saved = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        if threading.current_thread() is threading.main_thread():
            for number, handler in saved.items():
                signal.signal(number, handler)


def _check_folder(folder: Path, recursive: bool) -> ImageFolder:
    check_folder(folder, recursive)  # missing, a file, or no image in it: one line naming the fix
    return ImageFolder(folder, recursive=recursive)


def _trainer(devices: int, writer: JsonlWriter, progress_bar: bool) -> L.Trainer:
    return L.Trainer(
        accelerator="cpu",  # LSD and the candidate sampling run on the CPU anyway
        devices=devices,
        # forked processes start at once, with the imports and the weights of this one; a fresh interpreter per
        # process (Lightning's "ddp") costs seconds, more than a second process saves on a few hundred images
        strategy="ddp_fork" if devices > 1 else "auto",
        callbacks=[writer],
        logger=False,
        enable_progress_bar=progress_bar,
        enable_model_summary=False,
    )


def _check_out(out: Path, images: ImageFolder) -> Path:
    """The file the rows replace: ``out``, or the file it links to (the link stays a link). Refused: a folder, a
    device or pipe, one of the images (by any name, hard links too), and an existing file that holds no rows of
    ``ngp predict`` (it would be lost)."""
    if out.is_dir():
        raise OutputError(f"--out {out} is a folder; give the .jsonl file to write, e.g. {out / 'results.jsonl'}")
    target = out.resolve()
    if target.exists() and not target.is_file():
        raise OutputError(f"--out {out} is not a regular file (a device or a pipe); give a file, e.g. results.jsonl")
    if any(same_file(path, target) for path in images.paths):
        raise OutputError(f"--out {out} is one of the input images; give another file, e.g. results.jsonl")
    if target.is_file() and not _holds_rows(target):
        raise OutputError(
            f"--out {out} exists and holds no rows of ngp predict, so it would be lost; give another file or remove it"
        )
    return target


def _holds_rows(path: Path) -> bool:
    """Whether a file may be replaced: empty, or its first line a row as :class:`JsonlWriter` writes them."""
    try:
        with path.open("rb") as f:
            first = f.readline(1 << 20)
    except OSError:
        return False
    if not first.strip():
        return True
    try:
        row = json.loads(first)
    except (ValueError, UnicodeDecodeError):
        return False
    return isinstance(row, dict) and "image" in row


def cap_devices(devices: int) -> int:
    """``devices`` capped at :func:`usable_cores`, with a warning when capped: each process runs the parser on one
    thread, so more processes than cores only take turns on the same cores (and each costs its own memory)."""
    cores = usable_cores()
    if devices > cores:
        warnings.warn(
            f"devices={devices} is more than the {cores} CPU cores this process may use; using {cores}", stacklevel=2
        )
    return min(devices, cores)


def predict_folder(
    folder: str | Path,
    out: str | Path,
    devices: int = 1,
    weights: str | Path = "default",
    recursive: bool = False,
    batch_size: int = 1,
    seed: int = 0,
    num_workers: int = 0,
    config: ParserConfig | None = None,
    progress_bar: bool = False,
    priors: Priors | None = None,
    exif: bool = False,
    same_camera: bool = False,  # each folder's photos share a focal length: folder_cameras()
) -> dict | None:
    """Calibrate every image of a folder into a JSON Lines file, one row per image in sorted path order.

    A row is :func:`~ngp_kornia.rows.result_row` of its path relative to folder (``ngp calibrate --json``'s), or
    ``{"image": ..., "error": <reason>}`` for a file that cannot be read or calibrated, whatever the reason. An
    interrupted run (Ctrl+C or SIGTERM; the caller's handlers are back after) leaves ``out`` holding the rows of the
    images finished so far and returns with ``"interrupted": True``; it does not resume. What killed runs left
    beside ``out`` goes first (:func:`remove_stale_files`). With ``devices > 1`` the work is split over that many CPU
    processes forked from this one (``"ddp_fork"``, gloo; not on Windows), at most one per image and per core.

    Args:
        folder: the folder of images.
        out: the ``.jsonl`` file to write (replaced at the end if it holds an earlier run's rows; see Raises).
        devices: number of processes.
        weights: a weight set name or weights file, as for :func:`ngp_kornia.calibrate`.
        recursive: also calibrate the images of sub-folders.
        batch_size: images per loader batch (each image is still calibrated on its own).
        seed: seed of the candidate sampling, as for :func:`ngp_kornia.calibrate`.
        num_workers: loader worker processes per device, to read images while the parser runs.
        config, priors, exif: settings, priors (or, with ``exif``, read from the file), as for ``calibrate()``.
        progress_bar: show Lightning's progress bar.

    Returns:
        ``{"images": rows written, "errors": error rows, "interrupted": bool}``.

    Raises:
        FileNotFoundError: ``folder`` does not exist.
        NotADirectoryError: ``folder`` is a file.
        ValueError: no images in ``folder``, ``devices`` or ``batch_size`` below 1, unknown weights.
        OutputError: ``out`` an image, a folder, a device or a file of no rows (a link's file gets the rows); or the
            run stopped on an error (full disk, size limit, a process died): the message says where the rows are.
    """
    _check_counts(devices, batch_size)
    images = _check_folder(Path(folder), recursive)
    out = _check_out(Path(out), images)
    devices = min(cap_devices(devices), len(images))  # Lightning's predict sampler refuses a process without an image
    cameras = folder_cameras(images, weights, seed, config, priors, exif) if same_camera else None
    module = FolderPredictor(parser := load_parser(weights, config), images.root, seed, priors, exif, cameras)
    files = FolderImages(images, parser.config.segments, devices if num_workers == 0 else None)  # reads ahead
    loader = DataLoader(files, batch_size=batch_size, num_workers=num_workers, collate_fn=collate_items)
    writer = JsonlWriter(out, devices)
    try:
        _run(_trainer(devices, writer, progress_bar), module, loader, writer)
    finally:
        files.close()
    return {"images": writer.images, "errors": writer.errors, "interrupted": writer.interrupted}


def folder_cameras(images: ImageFolder, weights, seed: int, config, priors, exif: bool) -> dict[str, SharedFocal]:
    """The focal length shared by the photos of each folder (:func:`ngp_kornia.api.shared_focal`), by the folder's
    path relative to the root (``"."`` for the root): estimated in this process before the run, whose every
    photo then takes its folder's as known (``shared_photos`` in its row). A folder where fewer than two photos
    have lines shares nothing (its photos are calibrated alone) and is left out, with one
    :class:`~ngp_kornia.errors.NGPWarning` naming such folders.

    Raises:
        ValueError: with ``exif`` (a focal length per photo, where one is shared), or a folder of photos of
            different sizes.
    """
    if exif:
        raise ValueError("--same-camera estimates one focal length per folder; --exif gives each photo its own: "
                         "use one of them")
    groups: dict[str, list[Path]] = {}
    for path in images.paths:
        groups.setdefault(path.relative_to(images.root).parent.as_posix(), []).append(path)
    cameras = {name: shared_focal(paths, weights, seed, config, priors) for name, paths in groups.items()}
    alone = sorted(name for name, camera in cameras.items() if camera.photos < 2)
    if alone:  # said once for all such folders: a tree of one photo per folder would say it hundreds of times
        warnings.warn(NGPWarning(not_shared_folders(alone, len(cameras))), stacklevel=3)
    return {name: camera for name, camera in cameras.items() if camera.photos >= 2}


def _check_counts(devices: int, batch_size: int) -> None:
    if devices < 1:
        raise ValueError(f"devices must be at least 1, got {devices}")
    if batch_size < 1:
        raise ValueError(f"batch size must be at least 1, got {batch_size}")


def _run(trainer: L.Trainer, module: FolderPredictor, loader: DataLoader, writer: JsonlWriter) -> None:
    """``trainer.predict`` with Lightning's noise filtered, and Ctrl+C ending the run with the finished rows kept."""
    remove_stale_files(writer.out)
    # fork from one thread (OpenCV's worker pool does not survive a fork: a child would wait for threads that are
    # not there); each process runs LSD's strips on its share of the cores less the one its parser runs on
    strip_threads = max(1, usable_cores() // trainer.num_devices - 1)
    with pipeline_threads(1), line_workers(strip_threads), warnings.catch_warnings():
        # the parser, not the loader, is the bottleneck; and the pytree notice is between Lightning and torch
        warnings.filterwarnings("ignore", message=".*does not have many workers.*")
        warnings.filterwarnings("ignore", message=".*LeafSpec.*is deprecated.*", category=FutureWarning)
        # Lightning lets a prediction run on through SIGTERM, and ignores Ctrl+C once it has seen one: both are
        # stops here (forked processes inherit it), and the caller's handlers come back after
        with _signals_restored():
            _stop_like_ctrl_c()
            try:
                trainer.predict(module, loader, return_predictions=False)
            except SystemExit:  # Lightning's answer to Ctrl+C: the writer has kept the finished rows
                if not writer.interrupted:
                    raise
            except (OSError, ProcessException) as err:  # a full disk, a file-size limit, a forked process that died
                raise OutputError(_stopped(err, writer)) from None
    if writer.multi and not writer.interrupted:  # the forked processes wrote and merged; this one only waited
        writer.images, writer.errors = count_rows(writer.out)


def _stopped(err: BaseException, writer: JsonlWriter) -> str:
    """The one line for a run that an error stopped: the reason (a forked process's last traceback line), and
    where the rows finished are."""
    lines = str(err).strip().splitlines() or [type(err).__name__]
    reason = lines[-1] if isinstance(err, ProcessException) else " ".join(lines)
    kept = f"the {writer.images} rows finished are in {writer.out}" if writer.kept else f"{writer.out} is unchanged"
    return f"the run stopped: {reason}; {kept}"
