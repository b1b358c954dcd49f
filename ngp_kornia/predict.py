"""Calibrating a whole folder with Lightning's ``Trainer.predict``, one JSON line per image, in one or several
processes (``ngp predict FOLDER --out results.jsonl --devices N``).

Rows are written as batches finish and nothing is kept in memory, so a folder of any size can be processed. With
several processes (DDP on the CPU, gloo backend) each rank writes its own part file ``<out>.rank<R>`` holding
``<dataset index>\\t<json>`` lines; after a barrier rank 0 merges the parts in dataset order into ``out``, keeping
each index once, and deletes them.

Every image is calibrated on its own, exactly as :func:`ngp_kornia.calibrate` does for a file (LSD on the decoded
8-bit image, the candidate sampling seeded per call), so a row equals what ``ngp calibrate`` prints for that file.
"""

from __future__ import annotations

import heapq
import json
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

from ngp_kornia.api import load_parser
from ngp_kornia.data.folder import IMAGE_EXTENSIONS, ImageFolder
from ngp_kornia.models import Calibration, NeuralGeometricParser, ParserConfig

__all__ = ["FolderImages", "FolderItem", "FolderPredictor", "JsonlWriter", "merge_parts", "predict_folder"]


class FolderItem(NamedTuple):
    """One file of the folder: its dataset index, its path relative to the folder, and the (3, H, W) float image
    in [0, 1] or the reason it could not be read."""

    index: int
    name: str
    image: Tensor | None
    error: str | None


class FolderImages(Dataset):
    """The files of an :class:`ImageFolder` as :class:`FolderItem` records; an unreadable file gives an item with
    its error instead of raising, so a run writes a row for every file."""

    def __init__(self, folder: ImageFolder) -> None:
        self.folder = folder

    def __len__(self) -> int:
        return len(self.folder)

    def __getitem__(self, index: int) -> FolderItem:
        path, image, error = self.folder.safe_load(index)
        return FolderItem(index, path.relative_to(self.folder.root).as_posix(), image, error)


def collate_items(items: list[FolderItem]) -> list[FolderItem]:
    """Keep a batch as a list: the images of a folder may all differ in size."""
    return items


class FolderPredictor(L.LightningModule):
    """The parser as a LightningModule whose ``predict_step`` turns a batch of :class:`FolderItem` into
    ``(index, row)`` pairs, ``row`` being ``{"image": name, **Calibration.to_dict()}`` or
    ``{"image": name, "error": reason}``.

    Args:
        parser: the pipeline (see :func:`ngp_kornia.api.load_parser`); its config holds the seed.
    """

    def __init__(self, parser: NeuralGeometricParser) -> None:
        super().__init__()
        self.parser = parser

    def calibrate(self, image: Tensor) -> Calibration:
        """Calibrate one (3, H, W) image as :func:`ngp_kornia.calibrate` does for a file."""
        # the parser detects lines on the image rounded to 8 bits, which are the exact pixels the file decoded to
        # (the float image is uint8 / 255): the same lines, hence the same answer, as calibrate() on the file
        return self.parser(image[None].to(self.device))[0]

    def predict_step(self, batch: list[FolderItem], batch_idx: int) -> list[tuple[int, dict]]:
        rows = []
        for item in batch:  # one by one: the seeded sampling then gives calibrate()'s answer for every image
            if item.error is not None:
                rows.append((item.index, {"image": item.name, "error": item.error}))
                continue
            try:
                rows.append((item.index, {"image": item.name, **self.calibrate(item.image).to_dict()}))
            except ValueError as err:
                rows.append((item.index, {"image": item.name, "error": str(err)}))
        return rows


class JsonlWriter(BasePredictionWriter):
    """Writes each batch's rows as soon as it is predicted: straight to ``out`` in a single process, to the part
    file ``<out>.rank<R>`` (lines ``<index>\\t<json>``) in a multi-process run, which rank 0 then merges into
    ``out``.

    Attributes:
        images: rows written by this process; after the run, on every rank, the total over all ranks.
        errors: error rows, counted the same way.
    """

    def __init__(self, out: str | Path) -> None:
        super().__init__(write_interval="batch")
        self.out = Path(out)
        self.file: IO[str] | None = None
        self.multi = False
        self.images = self.errors = 0

    def part(self, rank: int) -> Path:
        """The part file of a rank."""
        return self.out.with_name(f"{self.out.name}.rank{rank}")

    def on_predict_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.multi = trainer.world_size > 1
        self.images = self.errors = 0
        self.out.parent.mkdir(parents=True, exist_ok=True)
        path = self.part(trainer.global_rank) if self.multi else self.out
        self.file = path.open("w", encoding="utf-8")

    def write_on_batch_end(
        self, trainer, pl_module, prediction, batch_indices, batch, batch_idx: int, dataloader_idx: int = 0
    ) -> None:
        for index, row in prediction:
            line = json.dumps(row)
            self.file.write(f"{index}\t{line}\n" if self.multi else line + "\n")
            self.images += 1
            self.errors += "error" in row
        self.file.flush()  # rows become visible as they are made, and survive a crash later in the run

    def on_predict_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.close()
        if not self.multi:
            return
        counts = torch.tensor([self.images, self.errors])
        self.images, self.errors = (int(v) for v in trainer.strategy.reduce(counts, reduce_op="sum"))
        trainer.strategy.barrier("ngp_predict_parts_written")
        if trainer.is_global_zero:
            parts = [self.part(rank) for rank in range(trainer.world_size)]
            self.images = merge_parts(parts, self.out)
            for part in parts:
                part.unlink()

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        self.close()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None


def _read_part(path: Path) -> Iterator[tuple[int, str]]:
    with path.open(encoding="utf-8") as lines:
        for line in lines:
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
        strategy="ddp" if devices > 1 else "auto",
        callbacks=[writer],
        logger=False,
        enable_progress_bar=progress_bar,
        enable_model_summary=False,
    )


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
) -> dict | None:
    """Calibrate every image of a folder into a JSON Lines file, one row per image in sorted path order.

    A row is ``{"image": <path relative to folder>, **Calibration.to_dict()}``, or ``{"image": ..., "error":
    <reason>}`` for a file that cannot be read. With ``devices > 1`` the work is split over that many CPU processes
    (Lightning's ``"ddp"`` strategy, gloo backend), at most one per image. Lightning starts them by running the
    current command again, so call this from a script or a command, not from an interactive session.

    Args:
        folder: the folder of images.
        out: the ``.jsonl`` file to write (replaced if it exists).
        devices: number of processes.
        weights: a weight set name or weights file, as for :func:`ngp_kornia.calibrate`.
        recursive: also calibrate the images of sub-folders.
        batch_size: images per loader batch (each image is still calibrated on its own).
        seed: seed of the candidate sampling, as for :func:`ngp_kornia.calibrate`.
        num_workers: loader worker processes per device, to read images while the parser runs.
        config: pipeline settings.
        progress_bar: show Lightning's progress bar.

    Returns:
        ``{"images": rows written, "errors": error rows}`` in the main process; None in the other processes of a
        multi-process run.

    Raises:
        FileNotFoundError: ``folder`` does not exist.
        NotADirectoryError: ``folder`` is a file.
        ValueError: no images in ``folder``, ``devices`` or ``batch_size`` below 1, unknown weights.
    """
    if devices < 1:
        raise ValueError(f"devices must be at least 1, got {devices}")
    if batch_size < 1:
        raise ValueError(f"batch size must be at least 1, got {batch_size}")
    images = _check_folder(Path(folder), recursive)
    devices = min(devices, len(images))  # Lightning's predict sampler refuses a process without an image
    module = FolderPredictor(load_parser(weights, replace(config or ParserConfig(), seed=seed)))
    loader = DataLoader(FolderImages(images), batch_size=batch_size, num_workers=num_workers, collate_fn=collate_items)
    writer = JsonlWriter(out)
    trainer = _trainer(devices, writer, progress_bar)
    with warnings.catch_warnings():
        # the parser, not the loader, is the bottleneck; and the pytree notice is between Lightning and torch
        warnings.filterwarnings("ignore", message=".*does not have many workers.*")
        warnings.filterwarnings("ignore", message=".*LeafSpec.*is deprecated.*", category=FutureWarning)
        trainer.predict(module, loader, return_predictions=False)
    if not trainer.is_global_zero:
        return None
    return {"images": writer.images, "errors": writer.errors}
