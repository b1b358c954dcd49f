"""Calibrating a whole collection with Lightning's ``Trainer.predict``, one JSON line per image: the images of a
folder (``ngp predict FOLDER --out results.jsonl``) or of a list file (``--list FILE``), on the CPU or GPUs
(``--accelerator``), in one or several processes (``--devices``) on one or several machines (``--num-nodes``).

Rows are written as batches finish and nothing is kept in memory, so a collection of any size can be processed.
Each process appends its rows to its own file in a hidden run folder beside ``out`` (:mod:`ngp_kornia.rowfiles`);
at the end the process of global rank 0 merges them in input order, each image once, into ``out`` through a
temporary file renamed over it, so ``out`` is never half-written. ``out`` must be on a file system that every
process sees. Lightning's strategies share out the work: the processes of one machine are forked from the calling
one (``ddp_fork``); over several machines, or where torchrun or SLURM started the processes, each process is a
command of its own (``ddp``), and Lightning reads the environment they set (``NODE_RANK``, ``MASTER_ADDR``,
``MASTER_PORT``, ``LOCAL_RANK``, ``WORLD_SIZE``, SLURM's variables). The networks run on the accelerator; the
images are read and their lines detected on a thread of each process, or in ``num_workers`` DataLoader workers.

Every image is isolated: any exception while reading or calibrating it becomes its error row, never the end of the
run. An interrupted run (Ctrl+C, SIGINT, or SIGTERM as ``kill``, service managers and job schedulers send) still
leaves ``out`` holding the rows of the images finished so far, in input order, and the run reports it. A run stopped
at any point, SIGKILL and a power cut included, keeps the rows it finished in its run folder: ``resume=True``
(``--resume``) calibrates only the images without a row and ends with one row per image, as if the run had never
stopped, provided the images and the options are the same (checked: a digest of both is in the run folder).
Without it a run starts over: it deletes what an earlier run left (unless a run still going holds it).

Every image is calibrated on its own, exactly as :func:`ngp_kornia.calibrate` does for a file (LSD on the decoded
8-bit image, the candidate sampling seeded per image), so on the CPU a row equals what ``ngp calibrate`` prints for
that file.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

from torch import Tensor
from torch.multiprocessing.spawn import ProcessException
from torch.utils.data import DataLoader

try:  # an optional dependency: calibrate() and the rest of the core run without it
    import lightning as L
    from lightning.fabric.plugins.environments import SLURMEnvironment, TorchElasticEnvironment
    from lightning.pytorch.accelerators import CUDAAccelerator, MPSAccelerator
except ImportError as err:
    raise ImportError(
        f"folder prediction needs Lightning ({err}); install it with: pip install 'ngp-kornia[train]'"
    ) from err

from ngp_kornia.api import file_priors, load_parser, shared_focal, with_orientation
from ngp_kornia.data.folder import ImageFolder
from ngp_kornia.data.image_list import ImageList, read_image_list
from ngp_kornia.errors import NGPError, NGPWarning, OutputError
from ngp_kornia.folder_items import FolderImages, FolderItem, collate_items, error_reason
from ngp_kornia.pipeline import Calibration, NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.priors import Priors, checked_seed
from ngp_kornia.pipeline.segments import line_workers
from ngp_kornia.pipeline.shared_camera import SharedFocal, not_shared_folders, with_shared_focal
from ngp_kornia.predict_plan import RunPlan, plan_run
from ngp_kornia.predict_writer import JsonlWriter, ProgressBar, signals_restored, stop_like_ctrl_c
from ngp_kornia.preflight import check_folder
from ngp_kornia.rowfiles import count_rows, merge_parts, remove_stale_files
from ngp_kornia.rows import result_row
from ngp_kornia.threads import pipeline_threads, usable_cores

__all__ = [
    "ACCELERATORS",
    "AcceleratorError",
    "FolderPredictor",
    "JsonlWriter",
    "RunPlan",
    "cap_devices",
    "folder_cameras",
    "forks_processes",
    "merge_parts",
    "plan_run",
    "predict_folder",
    "predict_images",
    "predict_list",
    "remove_stale_files",
    "resolve_accelerator",
    "run_plan",
    "usable_cores",
]

#: what ``accelerator`` may be
ACCELERATORS = ("cpu", "gpu", "auto")


class AcceleratorError(NGPError, ValueError):
    """An accelerator or a device count this machine does not have (``--accelerator gpu`` without a GPU)."""


class FolderPredictor(L.LightningModule):
    """The parser as a LightningModule whose ``predict_step`` turns a batch of :class:`FolderItem` into
    ``(index, row)`` pairs (none for an item of index -1), ``row`` being :func:`~ngp_kornia.rows.result_row`
    (``ngp calibrate --json``'s) or ``{"image": name, "error": reason}``.

    Args:
        parser: the pipeline (see :func:`ngp_kornia.api.load_parser`).
        root: the folder the item names are relative to (for items that do not carry their file's path); with
            ``exif`` the files' EXIF focal lengths are read from there.
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
        self,
        image: Tensor,
        name: str | None = None,
        segments: Tensor | None = None,
        mask: Tensor | None = None,
        path: str | Path | None = None,
    ) -> Calibration:
        """Calibrate one (3, H, W) image as :func:`ngp_kornia.calibrate` does for a file (``path``, else ``name``
        relative to ``root``, is where an EXIF focal length is read from; ``segments`` (1, N, 2, 2) and ``mask``
        (1, N): its lines when already detected)."""
        priors = self.priors
        if path is None and name is not None and self.root is not None:
            path = self.root / name
        if path is not None:  # the image's own prior, where its file records one
            priors = file_priors(path, image.shape[-2], image.shape[-1], priors, self.exif)
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
            if item.index < 0:  # a place that evens out the processes' shares: no image, no row
                continue
            if item.error is not None:
                rows.append((item.index, {"image": item.name, "error": item.error}))
                continue
            try:
                result = self.calibrate(item.image, item.name, item.segments, item.mask, item.path)
                if item.orientation is not None:
                    result = with_orientation(result, item.orientation)
                rows.append((item.index, result_row(item.name, result)))
            except Exception as err:  # one image's failure is its row, never the end of the run
                rows.append((item.index, {"image": item.name, "error": error_reason(err, item.name)}))
        return rows


def resolve_accelerator(accelerator: str, devices: int = 1) -> str:
    """The accelerator a run uses, ``"cpu"`` or ``"gpu"`` (CUDA, or Apple's MPS): ``"auto"`` takes a GPU where
    there is one.

    Raises:
        AcceleratorError: an unknown name, ``"gpu"`` where there is none, or more devices than GPUs.

    Example:
        >>> resolve_accelerator("cpu")
        'cpu'
    """
    if accelerator not in ACCELERATORS:
        raise AcceleratorError(f"--accelerator {accelerator!r}: give one of {', '.join(ACCELERATORS)}")
    if accelerator == "cpu":
        return "cpu"
    gpus = CUDAAccelerator.auto_device_count() if CUDAAccelerator.is_available() else int(MPSAccelerator.is_available())
    if accelerator == "auto":
        return "gpu" if gpus else "cpu"
    if not gpus:
        raise AcceleratorError("--accelerator gpu: this machine has no GPU that torch can use (no CUDA or MPS "
                               "device); use --accelerator cpu, or auto to take a GPU only where there is one")
    if devices > gpus:
        raise AcceleratorError(f"--devices {devices}: this machine has {gpus} GPU(s); give at most {gpus}")
    return "gpu"


def _launched_externally() -> bool:
    """Whether torchrun, SLURM's srun or Lightning's own launcher started this process as one of a run's."""
    return "LOCAL_RANK" in os.environ or TorchElasticEnvironment.detect() or SLURMEnvironment.detect()


def forks_processes(devices: int, num_nodes: int = 1) -> bool:
    """Whether a run forks its processes from the calling one (and may cap them at the cores), rather than a
    scheduler, torchrun or another machine starting each as a command of its own.

    Example:
        >>> forks_processes(1)
        False
    """
    return _strategy(devices, num_nodes) == "ddp_fork"


def _strategy(devices: int, num_nodes: int) -> str:
    if devices * num_nodes == 1:
        return "auto"
    if num_nodes > 1 or _launched_externally():  # each process is a command of its own
        return "ddp"
    # forked processes start at once, with the imports and the weights of this one; a fresh interpreter per
    # process (Lightning's "ddp") costs seconds, more than a second process saves on a few hundred images
    return "ddp_fork"


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
    accelerator: str = "cpu",
    num_nodes: int = 1,
    resume: bool = False,
) -> dict:
    """Calibrate every image of a folder into a JSON Lines file, one row per image in sorted path order.

    A row is :func:`~ngp_kornia.rows.result_row` of its path relative to folder (``ngp calibrate --json``'s), or
    ``{"image": ..., "error": <reason>}`` for a file that cannot be read or calibrated, whatever the reason. An
    interrupted run (Ctrl+C or SIGTERM; the caller's handlers are back after) leaves ``out`` holding the rows of the
    images finished so far and returns with ``"interrupted": True``; ``resume=True`` then calibrates the rest.

    Args:
        folder: the folder of images.
        out: the ``.jsonl`` file to write (replaced at the end if it holds an earlier run's rows; see Raises).
        devices: processes per machine: CPU processes (at most one per core), or GPUs.
        weights: a weight set name or weights file, as for :func:`ngp_kornia.calibrate`.
        recursive: also calibrate the images of sub-folders.
        batch_size: images per loader batch (each image is still calibrated on its own).
        seed: seed of the candidate sampling, as for :func:`ngp_kornia.calibrate`.
        num_workers: DataLoader worker processes per device that read the images and detect their lines (0: a
            thread of each process reads the next image while the parser works).
        config, priors, exif: settings, priors (or, with ``exif``, read from the file), as for ``calibrate()``.
        progress_bar: show a progress bar (on stderr) with the rate and the time left.
        same_camera: the photos of each folder share one focal length (:func:`folder_cameras`).
        accelerator: ``"cpu"``, ``"gpu"`` or ``"auto"`` (a GPU where there is one) for the networks.
        num_nodes: machines; each runs this call (the same arguments) with the environment Lightning reads.
        resume: continue the unfinished run for ``out``: only the images without a row are calibrated.

    Returns:
        ``{"images": rows written, "errors": error rows, "interrupted": bool, "rank": global rank}``; the counts
        are those of ``out`` in the process that wrote it (rank 0), of the process's own rows in the others.

    Raises:
        FileNotFoundError: ``folder`` does not exist.
        NotADirectoryError: ``folder`` is a file.
        ValueError: no images in ``folder``, ``devices``, ``num_nodes`` or ``batch_size`` below 1, unknown weights.
        AcceleratorError: ``accelerator="gpu"`` without a GPU, or more devices than GPUs.
        OutputError: ``out`` an image, a folder, a device or a file of no rows (a link's file gets the rows);
            another run writing it; with ``resume``, an unfinished run of other images or options; or the run
            stopped on an error (full disk, size limit, a process died): the message says where the rows are.
    """
    check_folder(Path(folder), recursive)  # missing, a file, or no image in it: one line naming the fix
    options = {k: v for k, v in locals().items() if k not in ("folder", "out", "recursive")}
    return predict_images(ImageList.from_folder(ImageFolder(folder, recursive=recursive)), out, **options)


def predict_list(image_list: str | Path, out: str | Path, **options) -> dict:
    """:func:`predict_folder` for the images a list file names (one path per line, or a CSV file with a ``path``
    or ``image`` column; paths relative to the list file's folder; see :mod:`ngp_kornia.data.image_list`), one
    row per listed image in list order, its ``"image"`` the path as listed.

    Args:
        image_list: the list file.
        out: the ``.jsonl`` file to write.
        options: as for :func:`predict_folder` (but ``recursive``).

    Raises:
        FileNotFoundError: no list file, or none of the listed files exists.
        ManifestError: a list that names no image, or one image twice, or a CSV without a path column.
    """
    return predict_images(read_image_list(image_list), out, **options)


def predict_images(images: ImageList, out: str | Path, resume: bool = False, **options) -> dict:
    """:func:`predict_folder` for an :class:`~ngp_kornia.data.image_list.ImageList`: :func:`plan_run`, then
    :func:`run_plan`."""
    settings = {key: options.pop(key) for key in ("weights", "seed", "config", "priors", "exif", "same_camera")
                if key in options}
    _check_counts(options.get("devices", 1), options.get("batch_size", 1), options.get("num_nodes", 1))
    return run_plan(plan_run(images, out, resume, **settings), **options)


def run_plan(
    plan: RunPlan,
    devices: int = 1,
    batch_size: int = 1,
    num_workers: int = 0,
    progress_bar: bool = False,
    accelerator: str = "cpu",
    num_nodes: int = 1,
) -> dict:
    """Calibrate the images a :class:`RunPlan` has still to do (arguments and result as for
    :func:`predict_folder`)."""
    _check_counts(devices, batch_size, num_nodes, num_workers)
    accelerator = resolve_accelerator(accelerator, devices)
    if forks_processes(devices, num_nodes) and accelerator == "cpu":
        # forked here: at most one per core, and one per image to calibrate
        devices = min(cap_devices(devices), max(1, len(plan.todo)))
    settings = plan.settings
    cameras = folder_cameras(plan.images, **settings) if settings["same_camera"] else None
    parser = load_parser(settings["weights"], settings["config"])
    module = FolderPredictor(parser, plan.images.root, settings["seed"], settings["priors"], settings["exif"], cameras)
    writer = JsonlWriter(plan.out, len(plan.images), plan.state, plan.keep, devices * num_nodes)
    trainer = _trainer(accelerator, devices, num_nodes, writer, progress_bar, batch_size)
    world = trainer.world_size  # places past the images to do give every process one (a resumed run near its end)
    files = FolderImages(plan.images, parser.config.segments, world if num_workers == 0 else None, plan.todo, world)
    loader = DataLoader(files, batch_size=batch_size, num_workers=num_workers, collate_fn=collate_items)
    try:
        _run(trainer, module, loader, writer, num_workers)
    finally:
        files.close()
    return {"images": writer.images, "errors": writer.errors, "interrupted": writer.interrupted,
            "rank": trainer.global_rank}


def folder_cameras(
    images: ImageList | ImageFolder, weights="default", seed: int = 0, config=None, priors=None, exif: bool = False,
    **ignored,
) -> dict[str, SharedFocal]:
    """The focal length shared by the photos of each folder (:func:`ngp_kornia.api.shared_focal`), by the folder
    of the photo's name (its path relative to the root; ``"."`` for the root): estimated in this process before
    the run, whose every photo then takes its folder's as known (``shared_photos`` in its row). A folder where fewer
    than two photos have lines shares nothing (its photos are calibrated alone) and is left out, with one
    :class:`~ngp_kornia.errors.NGPWarning` naming such folders.

    Raises:
        ValueError: with ``exif`` (a focal length per photo, where one is shared), or a folder of photos of
            different sizes.
    """
    if exif:
        raise ValueError("--same-camera estimates one focal length per folder; --exif gives each photo its own: "
                         "use one of them")
    images = images if isinstance(images, ImageList) else ImageList.from_folder(images)
    groups: dict[str, list[Path]] = {}
    for index, name in enumerate(images.names):
        groups.setdefault(Path(name).parent.as_posix(), []).append(images.path(index))
    cameras = {name: shared_focal(paths, weights, seed, config, priors) for name, paths in groups.items()}
    alone = sorted(name for name, camera in cameras.items() if camera.photos < 2)
    if alone:  # said once for all such folders: a tree of one photo per folder would say it hundreds of times
        warnings.warn(NGPWarning(not_shared_folders(alone, len(cameras))), stacklevel=3)
    return {name: camera for name, camera in cameras.items() if camera.photos >= 2}


def _check_counts(devices: int, batch_size: int, num_nodes: int = 1, num_workers: int = 0) -> None:
    for name, value, least in (("devices", devices, 1), ("batch size", batch_size, 1), ("num_nodes", num_nodes, 1),
                               ("num_workers", num_workers, 0)):
        if value < least:
            raise ValueError(f"{name} must be at least {least}, got {value}")


def _trainer(accelerator: str, devices: int, num_nodes: int, writer: JsonlWriter, progress_bar: bool,
             batch_size: int = 1) -> L.Trainer:
    bar = ProgressBar("image" if batch_size == 1 else "batch")
    return L.Trainer(
        accelerator=accelerator,
        devices=devices,
        num_nodes=num_nodes,
        strategy=_strategy(devices, num_nodes),
        callbacks=[writer, bar] if progress_bar else [writer],
        logger=False,
        enable_progress_bar=progress_bar,
        enable_model_summary=False,
    )


def _run(trainer: L.Trainer, module: FolderPredictor, loader: DataLoader, writer: JsonlWriter, workers: int) -> None:
    """``trainer.predict`` with Lightning's noise filtered, and Ctrl+C ending the run with the finished rows kept."""
    # fork from one thread (OpenCV's worker pool does not survive a fork: a child would wait for threads that are
    # not there); each process runs LSD's strips on its share of the cores less the one its parser runs on
    readers = trainer.num_devices * max(1, workers)
    strip_threads = max(1, usable_cores() // readers - (workers == 0))
    with pipeline_threads(1), line_workers(strip_threads), warnings.catch_warnings():
        # the parser, not the loader, is the bottleneck; and the pytree notice is between Lightning and torch
        warnings.filterwarnings("ignore", message=".*does not have many workers.*")
        warnings.filterwarnings("ignore", message=".*LeafSpec.*is deprecated.*", category=FutureWarning)
        # Lightning lets a prediction run on through SIGTERM, and ignores Ctrl+C once it has seen one: both are
        # stops here (forked processes inherit it), and the caller's handlers come back after
        with signals_restored():
            stop_like_ctrl_c()
            try:
                trainer.predict(module, loader, return_predictions=False)
            except SystemExit:  # Lightning's answer to Ctrl+C: the writer has kept the finished rows
                if not writer.interrupted:
                    raise
            except (OSError, ProcessException) as err:  # a full disk, a file-size limit, a forked process that died
                raise OutputError(_stopped(err, writer)) from None
    if trainer.is_global_zero and not (writer.interrupted or writer.kept):  # forked processes wrote and merged
        writer.images, writer.errors = count_rows(writer.out)


def _stopped(err: BaseException, writer: JsonlWriter) -> str:
    """The one line for a run that an error stopped: the reason (a forked process's last traceback line), and
    where the rows finished are."""
    lines = str(err).strip().splitlines() or [type(err).__name__]
    reason = lines[-1] if isinstance(err, ProcessException) else " ".join(lines)
    kept = f"the {writer.images} rows finished are in {writer.out}" if writer.kept else f"{writer.out} is unchanged"
    return f"the run stopped: {reason}; {kept}"
