"""Calibrating a whole folder with Lightning's ``Trainer.predict``, one JSON line per image, in one or several
processes (``ngp predict FOLDER --out results.jsonl --devices N``).

Rows are written as batches finish and nothing is kept in memory, so a folder of any size can be processed. They go
to a hidden temporary file beside ``out`` (``.<out name>.<run id>.tmp``) that is renamed to ``out`` at the end, so
``out`` is never half-written. With several processes (forked from this one; DDP on the CPU, gloo backend) each
rank writes its own part file ``.<out name>.<run id>.part<R>`` holding ``<dataset index>\\t<json>`` lines; after a
barrier rank 0 merges the parts in dataset order, keeping each index once, and deletes them (the run id is drawn
per run, so no other file is ever touched). An ``out`` that is one of the input images is refused.

Every image is isolated: any exception while reading or calibrating it becomes its error row, never the end of the
run. An interrupted run (Ctrl+C, SIGINT) still leaves ``out`` holding the rows of the images finished so far, in
folder order, and the run reports it; it does not resume: running the command again starts over.

Every image is calibrated on its own, exactly as :func:`ngp_kornia.calibrate` does for a file (LSD on the decoded
8-bit image, the candidate sampling seeded per image), so a row equals what ``ngp calibrate`` prints for that file.
"""

from __future__ import annotations

import heapq
import json
import secrets
import signal
import warnings
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import IO, NamedTuple

import torch
from torch import Tensor
from torch.utils.data import DataLoader, Dataset

try:  # an optional dependency: calibrate() and the rest of the core run without it
    import lightning as L
    from lightning.pytorch.callbacks import BasePredictionWriter
except ImportError as err:
    raise ImportError(
        f"folder prediction needs Lightning ({err}); install it with: pip install 'ngp-kornia[train]'"
    ) from err

from ngp_kornia.api import file_priors, load_parser, shared_focal, with_orientation
from ngp_kornia.data.folder import IMAGE_EXTENSIONS, ImageFolder
from ngp_kornia.errors import OutputError
from ngp_kornia.io import read_rgb_oriented
from ngp_kornia.pipeline import Calibration, NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.priors import Priors, checked_seed
from ngp_kornia.pipeline.segments import detect_segments, line_workers
from ngp_kornia.pipeline.settings import SegmentSettings
from ngp_kornia.pipeline.shared_camera import SharedFocal, with_shared_focal
from ngp_kornia.threads import Lookahead, pipeline_threads, usable_cores

__all__ = [
    "FolderImages",
    "FolderItem",
    "FolderPredictor",
    "JsonlWriter",
    "cap_devices",
    "folder_cameras",
    "merge_parts",
    "predict_folder",
    "usable_cores",
]


class FolderItem(NamedTuple):
    """One file of the folder: its dataset index, its path relative to the folder, and the (3, H, W) float image
    in [0, 1] with its line segments (1, N, 2, 2) and mask (1, N), or the reason it could not be read."""

    index: int
    name: str
    image: Tensor | None
    error: str | None
    orientation: int | None = None
    segments: Tensor | None = None
    mask: Tensor | None = None


class FolderImages(Dataset):
    """The files of an :class:`ImageFolder` as :class:`FolderItem` records, each read and its lines detected as
    :func:`ngp_kornia.calibrate` does for a file; an unreadable file gives an item with its error instead of raising,
    so a run writes a row for every file.

    Args:
        folder: the files.
        settings: the line-detection settings (:class:`SegmentSettings`; the defaults when None).
        stride: the step between the indices one process asks for in turn (its DDP world size): the file it will
            ask for next is read on a second thread (:class:`~ngp_kornia.threads.Lookahead`) while the parser works
            on the current one; None reads each file only when asked (loader worker processes read ahead anyway).
    """

    def __init__(self, folder: ImageFolder, settings: SegmentSettings | None = None, stride: int | None = 1) -> None:
        self.folder = folder
        self.settings = settings or SegmentSettings()
        self.stride = stride
        self._ahead = Lookahead(self._read)

    def __len__(self) -> int:
        return len(self.folder)

    def __getitem__(self, index: int) -> FolderItem:
        if self.stride is None:
            return self._read(index)
        upcoming = index + self.stride
        return self._ahead.get(index, upcoming if upcoming < len(self) else None)

    def _read(self, index: int) -> FolderItem:
        path = self.folder.paths[index]
        name = path.relative_to(self.folder.root).as_posix()
        try:
            rgb, orientation = read_rgb_oriented(path)
            segments, mask = detect_segments(rgb, self.settings)
        except Exception as err:  # whatever goes wrong with one file is that file's error row
            return FolderItem(index, name, None, _reason(err, path))
        image = torch.from_numpy(rgb).permute(2, 0, 1).float().div(255.0)
        return FolderItem(index, name, image, None, orientation, segments, mask)

    def close(self) -> None:
        """Stop reading ahead."""
        self._ahead.close()


def _reason(err: BaseException, path) -> str:
    """One line for an error row: the message, naming the file."""
    text = " ".join(str(err).split()) or type(err).__name__
    if isinstance(err, OSError) and err.strerror:
        text = f"cannot read the file: {err.strerror}"
    elif not isinstance(err, ValueError):
        text = f"{type(err).__name__}: {text}"
    return text if str(path) in text else f"{path}: {text}"


def collate_items(items: list[FolderItem]) -> list[FolderItem]:
    """Keep a batch as a list: the images of a folder may all differ in size."""
    return items


class FolderPredictor(L.LightningModule):
    """The parser as a LightningModule whose ``predict_step`` turns a batch of :class:`FolderItem` into
    ``(index, row)`` pairs, ``row`` being ``{"image": name, **Calibration.to_dict()}`` or
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
            priors = replace(priors, focal=shared.focal, fov_v=None)
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
                rows.append((item.index, {"image": item.name, **result.to_dict()}))
            except Exception as err:  # one image's failure is its row, never the end of the run
                rows.append((item.index, {"image": item.name, "error": _reason(err, item.name)}))
        return rows


class JsonlWriter(BasePredictionWriter):
    """Writes each batch's rows as soon as it is predicted: to a temporary file beside ``out`` in a single process,
    to a part file per rank (lines ``<index>\\t<json>``) in a multi-process run, which rank 0 merges; the result
    is renamed to ``out`` at the end, or when the run is interrupted (then holding the images finished so far).

    In a multi-process run the processes are forked from the calling one, which only waits for them: its writer
    never sees a row, and on an interruption it merges the part files the processes left.

    Attributes:
        images: rows written; in the calling process of a multi-process run, after it, the rows of the merged file.
        errors: error rows, counted the same way.
        interrupted: the run was stopped (KeyboardInterrupt or an exception) before every image was done.
    """

    def __init__(self, out: str | Path, world: int = 1) -> None:
        super().__init__(write_interval="batch")
        self.out = Path(out)
        self.file: IO[str] | None = None
        self.multi = world > 1
        self.rank, self.world = 0, world
        self.run_id = secrets.token_hex(4)  # made before the fork, so every process names the same files
        self.images = self.errors = 0
        self.interrupted = False

    def part(self, rank: int) -> Path:
        """The part file of a rank (hidden, named by this run's id so no other file is ever touched)."""
        return self.out.with_name(f".{self.out.name}.{self.run_id}.part{rank}")

    @property
    def temporary(self) -> Path:
        """The file the rows go to before it is renamed to ``out``."""
        return self.out.with_name(f".{self.out.name}.{self.run_id}.tmp")

    def on_predict_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.multi = trainer.world_size > 1
        self.rank, self.world = trainer.global_rank, trainer.world_size
        self.images = self.errors = 0
        self.interrupted = False
        self.out.parent.mkdir(parents=True, exist_ok=True)
        path = self.part(self.rank) if self.multi else self.temporary
        self.file = path.open("w", encoding="utf-8")

    def write_on_batch_end(
        self, trainer, pl_module, prediction, batch_indices, batch, batch_idx: int, dataloader_idx: int = 0
    ) -> None:
        for index, row in prediction:
            line = json.dumps(row)
            self.file.write(f"{index}\t{line}\n" if self.multi else line + "\n")
            self.images += 1
            self.errors += "error" in row
        self.file.flush()  # rows survive an interruption or a crash later in the run

    def on_predict_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.close()
        if not self.multi:
            self.temporary.replace(self.out)
            return
        trainer.strategy.barrier("ngp_predict_parts_written")
        if trainer.is_global_zero:
            self.finish()  # the calling process counts the merged rows

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        """Interrupted: the main process keeps the rows finished so far, in folder order, as ``out``."""
        self.close()
        self.interrupted = True
        if self.rank != 0:
            return
        if self.multi:
            _wait_for(getattr(trainer.strategy.launcher, "procs", []))
            self.images = self.finish()
        elif self.temporary.exists():
            self.temporary.replace(self.out)

    def finish(self) -> int:
        """Merge the part files that exist into ``out`` (through the temporary file), delete them; rows written."""
        parts = [p for p in (self.part(rank) for rank in range(self.world)) if p.exists()]
        written = merge_parts(parts, self.temporary)
        self.temporary.replace(self.out)
        for part in parts:
            part.unlink(missing_ok=True)
        return written

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None


def _wait_for(processes: list, timeout: float = 30.0) -> None:
    """Let the forked processes of an interrupted run end (each stops at its next image) before their files are read."""
    for process in processes:
        process.join(timeout)


def count_rows(path: str | Path) -> tuple[int, int]:
    """Rows and error rows of a results file."""
    rows = errors = 0
    with Path(path).open(encoding="utf-8") as lines:
        for line in lines:
            rows += 1
            errors += "error" in json.loads(line)
    return rows, errors


def _read_part(path: Path) -> Iterator[tuple[int, str]]:
    with path.open(encoding="utf-8") as lines:
        for line in lines:
            if not line.endswith("\n"):  # a process stopped in the middle of a line: that image is not done
                return
            index, row = line.split("\t", 1)
            yield int(index), row


def merge_parts(parts: list[Path], out: str | Path) -> int:
    """Merge part files (lines ``<index>\\t<json>``, increasing index in each file) into ``out`` in index order,
    writing each index once; streams, so memory does not grow with the number of rows.

    Returns:
        the number of rows written.
    """
    written, last = 0, -1
    with Path(out).open("w", encoding="utf-8") as dst:
        for index, row in heapq.merge(*(_read_part(p) for p in parts), key=lambda pair: pair[0]):
            # a sampler that pads the last batch repeats indices: keep the first copy only
            if index == last:
                continue
            dst.write(row)
            written, last = written + 1, index
    return written


def _check_folder(folder: Path, recursive: bool) -> ImageFolder:
    if not folder.exists():
        raise FileNotFoundError(f"{folder}: no such folder; give the folder that holds the images")
    if not folder.is_dir():
        raise NotADirectoryError(f"{folder}: is a file, not a folder; for single images use ngp calibrate")
    images = ImageFolder(folder, recursive=recursive)
    if len(images) == 0:
        hint = "" if recursive else "; use --recursive for images in sub-folders"
        raise ValueError(f"{folder}: no images found (looked for {', '.join(IMAGE_EXTENSIONS)}){hint}")
    return images


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


def _check_out(out: Path, images: ImageFolder) -> None:
    if out.is_dir():
        raise OutputError(f"--out {out} is a folder; give the .jsonl file to write, e.g. {out / 'results.jsonl'}")
    target = out.resolve()
    if any(path.resolve() == target for path in images.paths):
        raise OutputError(f"--out {out} is one of the input images; give another file, e.g. results.jsonl")


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

    A row is ``{"image": <path relative to folder>, **Calibration.to_dict()}`` (with ``exif_orientation``), or
    ``{"image": ..., "error": <reason>}`` for a file that cannot be read or calibrated, whatever the reason. An
    interrupted run (Ctrl+C) leaves ``out`` holding the rows of the images finished so far and returns with
    ``"interrupted": True``; it does not resume. With ``devices > 1`` the work is split over that many CPU processes
    forked from this one (``"ddp_fork"``, gloo; not on Windows), at most one per image and per usable core.

    Args:
        folder: the folder of images.
        out: the ``.jsonl`` file to write (replaced if it exists, once the run ends; never one of the images).
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
        OutputError: ``out`` is one of the images, or a folder.
    """
    _check_counts(devices, batch_size)
    images = _check_folder(Path(folder), recursive)
    _check_out(Path(out), images)
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
    if writer.multi and not writer.interrupted:  # the forked processes wrote and merged; this one only waited
        writer.images, writer.errors = count_rows(writer.out)
    return {"images": writer.images, "errors": writer.errors, "interrupted": writer.interrupted}


def folder_cameras(images: ImageFolder, weights, seed: int, config, priors, exif: bool) -> dict[str, SharedFocal]:
    """The focal length shared by the photos of each folder (:func:`ngp_kornia.api.shared_focal`), by the folder's
    path relative to the root (``"."`` for the root): estimated in this process before the run, whose every
    photo then takes its folder's as known (``shared_photos`` in its row).

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
    return {name: shared_focal(paths, weights, seed, config, priors) for name, paths in groups.items()}


def _check_counts(devices: int, batch_size: int) -> None:
    if devices < 1:
        raise ValueError(f"devices must be at least 1, got {devices}")
    if batch_size < 1:
        raise ValueError(f"batch size must be at least 1, got {batch_size}")


def _run(trainer: L.Trainer, module: FolderPredictor, loader: DataLoader, writer: JsonlWriter) -> None:
    """``trainer.predict`` with Lightning's noise filtered, and Ctrl+C ending the run with the finished rows kept."""
    # fork from one thread (OpenCV's worker pool does not survive a fork: a child would wait for threads that are
    # not there); each process runs LSD's strips on its share of the cores less the one its parser runs on
    strip_threads = max(1, usable_cores() // trainer.num_devices - 1)
    with pipeline_threads(1), line_workers(strip_threads), warnings.catch_warnings():
        # the parser, not the loader, is the bottleneck; and the pytree notice is between Lightning and torch
        warnings.filterwarnings("ignore", message=".*does not have many workers.*")
        warnings.filterwarnings("ignore", message=".*LeafSpec.*is deprecated.*", category=FutureWarning)
        handler = signal.getsignal(signal.SIGINT)
        try:
            trainer.predict(module, loader, return_predictions=False)
        except SystemExit:  # Lightning's answer to Ctrl+C: the writer has kept the finished rows
            if not writer.interrupted:
                raise
        finally:
            signal.signal(signal.SIGINT, handler)  # Lightning ignores further Ctrl+C once it has seen one
