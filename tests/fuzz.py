"""The hostile-input battery: every way a file, a setting or a command line has been found to hurt the package, run
again as a new user and an attacker would, with a pass / fail table.

Every command runs in a child process under a memory limit this script sets (``resource.setrlimit(RLIMIT_AS)``,
``--memory-gb``, 3 GB by default), so a decompression bomb that got through would fail its case instead of taking
the machine down. Nothing is downloaded; the files are written into a temporary folder.

    OMP_NUM_THREADS=1 python tests/fuzz.py            # the whole battery (about 5 minutes on 2 CPU cores)
    OMP_NUM_THREADS=1 python tests/fuzz.py --quick    # without the Ctrl+C and two-process cases

The exit status is 0 when every case passes.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import signal
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import torch

import ngp_kornia
from ngp_kornia import ConfigError, InputError, NeuralGeometricParser, ParserConfig, calibrate
from ngp_kornia.errors import ImageReadError, NGPError, WeightsError
from ngp_kornia.nets.weights import FORMAT, VERSION, save_network
from ngp_kornia.nets.zsnet import ZSNet
from ngp_kornia.training.synth.render import render_scene

ROOT = Path(__file__).resolve().parents[1]
CASES: list[tuple[str, str, Callable[[Path], str]]] = []
MEMORY_GB = 3.0


def case(group: str, name: str):
    def register(fn):
        CASES.append((group, name, fn))
        return fn

    return register


class Failed(Exception):
    pass


def expect(condition: bool, detail: str) -> None:
    if not condition:
        raise Failed(detail)


# ------------------------------------------------------------------------------------------------------- helpers


def limit_memory() -> None:
    size = int(MEMORY_GB * (1 << 30))
    resource.setrlimit(resource.RLIMIT_AS, (size, size))


def env(**extra: str) -> dict:
    out = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    return {**out, **extra}


def run(args: list[str], timeout: float = 300, cwd: Path | None = None, **extra: str) -> subprocess.CompletedProcess:
    """``python -m <args>`` in a child under the memory limit."""
    return subprocess.run(
        [sys.executable, "-m", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env(**extra),
        cwd=cwd,
        preexec_fn=limit_memory,
    )


def ngp(*args: str, **extra) -> subprocess.CompletedProcess:
    return run(["ngp_kornia.cli", *[str(a) for a in args]], **extra)


def one_line(proc: subprocess.CompletedProcess, prefix: str = "ngp: error: ") -> str:
    """The single stderr line of a failed command; fails the case on a traceback or several lines."""
    err = proc.stderr
    expect("Traceback" not in err, f"traceback: {err[-300:]!r}")
    expect(err.count("\n") == 1 and err.startswith(prefix), f"expected one '{prefix}' line, got {err[-400:]!r}")
    return err.strip()


def weights_usage_error(proc: subprocess.CompletedProcess) -> str:
    """A bad ``--weights`` is a usage error (exit 2): the usage, then one line naming the file and the problem."""
    err = proc.stderr
    expect("Traceback" not in err, f"traceback: {err[-300:]!r}")
    last = err.strip().splitlines()[-1] if err.strip() else ""
    expect(proc.returncode == 2 and last.startswith("ngp calibrate: error: --weights: "), f"got {err[-400:]!r}")
    return last


def chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def bomb_png(width: int = 30000, height: int = 30000) -> bytes:
    """A real decompression bomb: a valid RGB PNG of zeros, about 2.6 MB declaring 30000 x 30000 (2.7 GB decoded).
    Built from one compressed block repeated (each ends in a full flush), so it takes a fraction of a second."""
    row, per_block = bytes(1 + 3 * width), 100
    block_writer = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = block_writer.compress(row * per_block) + block_writer.flush(zlib.Z_FULL_FLUSH)
    full, rest = divmod(height, per_block)
    tail_writer = zlib.compressobj(9, zlib.DEFLATED, -15)
    tail = tail_writer.compress(row * rest) + tail_writer.flush(zlib.Z_FINISH)
    n = len(row) * height
    adler = ((n % 65521) << 16) | 1  # Adler-32 of n zero bytes
    idat = b"\x78\xda" + block * full + tail + struct.pack(">I", adler)
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def exif_jpeg(rgb: np.ndarray, orientation: int) -> bytes:
    tiff = b"MM\x00*" + struct.pack(">IH", 8, 1) + struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0) + bytes(4)
    body = b"Exif\x00\x00" + tiff
    data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    return data[:2] + b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body + data[2:]


def scene_png(path: Path, seed: int = 0, size=(160, 120)) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(render_scene(seed, size=size).image, cv2.COLOR_RGB2BGR))
    return path


def jpeg_bytes(seed: int = 1) -> bytes:
    rgb = (np.random.default_rng(seed).random((96, 128, 3)) * 255).astype(np.uint8)
    return cv2.imencode(".jpg", rgb)[1].tobytes()


class Planted:
    """Unpickling it creates a folder: proof that reading a file ran code from it."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


# ------------------------------------------------------------------------------------------ files that run code


@case("code", "planted pickle in a weights file (ngp calibrate --weights)")
def _(tmp: Path) -> str:
    marker, weights = tmp / "ran", tmp / "evil.pt"
    torch.save({"format": FORMAT, "version": VERSION, "network": "ZSNet", "x": Planted(marker)}, weights)
    proc = ngp("calibrate", "--weights", weights, scene_png(tmp / "a.png"))
    line = weights_usage_error(proc)
    expect("refused" in line and not marker.exists(), line)
    return line


@case("code", "planted pickle in a checkpoint (ngp-train export)")
def _(tmp: Path) -> str:
    marker, ckpt = tmp / "ran", tmp / "evil.ckpt"
    net = ZSNet(width=8)
    state = {f"net.{k}": v for k, v in net.state_dict().items()}
    torch.save(
        {"state_dict": state, "ngp_network": {"name": "ZSNet", "settings": net.settings()}, "x": Planted(marker)}, ckpt
    )
    proc = run(["ngp_kornia.training.command", "export", str(ckpt), str(tmp / "out.pt")])
    line = one_line(proc, "ngp-train: error: ")
    expect(proc.returncode == 1 and "refused" in line and not marker.exists(), line)
    return line


@case("code", "planted pickle and a truncated file in the training cache (.npz)")
def _(tmp: Path) -> str:
    from ngp_kornia.training.scene_data import RenderedScenes

    scenes = RenderedScenes([0], cache_dir=tmp, size=(160, 120))
    good = scenes[0]
    path, marker = scenes.cache / "0.npz", tmp / "ran"
    np.savez(path, segments=np.array([Planted(marker)], dtype=object))
    expect(np.array_equal(scenes[0].segments, good.segments) and not marker.exists(), "pickle loaded or not recomputed")
    path.write_bytes(path.read_bytes()[:100])
    expect(np.array_equal(scenes[0].segments, good.segments), "truncated cache not recomputed")
    return "recomputed both times; the pickle never ran"


# ------------------------------------------------------------------------------------------------------- memory


@case("memory", "decompression bomb PNG (2.6 MB -> 2.7 GB) with ngp calibrate")
def _(tmp: Path) -> str:
    bomb = tmp / "bomb.png"
    bomb.write_bytes(bomb_png())
    proc = ngp("calibrate", bomb)
    line = one_line(proc)
    expect(proc.returncode == 1 and "over the limit" in line, line)
    return f"{bomb.stat().st_size / 1e6:.1f} MB file: {line}"


@case("memory", "bomb with NGP_MAX_PIXELS raised: Pillow's own limit still holds")
def _(tmp: Path) -> str:
    bomb = tmp / "bomb.png"
    bomb.write_bytes(bomb_png())
    proc = ngp("calibrate", bomb, NGP_MAX_PIXELS=str(10**10))
    line = one_line(proc)
    expect(proc.returncode == 1 and "limit" in line, line)
    return line


@case("memory", "bomb among good images in ngp predict: an error row, the run goes on")
def _(tmp: Path) -> str:
    folder = tmp / "photos"
    scene_png(folder / "a.png", 0)
    scene_png(folder / "c.png", 1)
    (folder / "b.png").write_bytes(bomb_png())
    out = tmp / "r.jsonl"
    proc = ngp("predict", folder, "--out", out)
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    expect(proc.returncode == 1 and [r["image"] for r in rows] == ["a.png", "b.png", "c.png"], proc.stderr[-300:])
    expect("over the limit" in rows[1]["error"] and "focal" in rows[0] and "focal" in rows[2], str(rows[1]))
    return "3 rows, b.png: " + rows[1]["error"][-60:]


@case("memory", "weights claiming width 1e5 (40 GB): refused before allocating")
def _(tmp: Path) -> str:
    path = tmp / "wide.pt"
    save_network(ZSNet(width=8), path, {"width": 8, "use_line_feature": True, "use_support": True})
    payload = torch.load(path, weights_only=True)
    payload["settings"]["width"] = 10**5
    torch.save(payload, path)
    proc = ngp("calibrate", "--weights", path, scene_png(tmp / "a.png"))
    line = weights_usage_error(proc)
    expect("does not fit a ZSNet" in line, line)
    return line[-100:]


# -------------------------------------------------------------------------------------------- right way up


@case("exif", "phone photo stored sideways (orientation 6): calibrated as displayed")
def _(tmp: Path) -> str:
    scene = render_scene(3)
    path = tmp / "phone.jpg"
    path.write_bytes(exif_jpeg(np.ascontiguousarray(np.rot90(scene.image, 1)), 6))
    proc = ngp("calibrate", path)
    expect(proc.returncode == 0, proc.stderr[-300:])
    row, truth = json.loads(proc.stdout), scene.to_dict()
    expect(row["exif_orientation"] == 6 and (row["height"], row["width"]) == scene.image.shape[:2], str(row)[:200])
    expect(abs(row["pitch"] - truth["pitch"]) < 1.5 and abs(row["fov_v"] - truth["fov_v"]) < 3.0, "wrong camera")
    return f"pitch {row['pitch']:.2f} (truth {truth['pitch']:.2f}), fov_v {row['fov_v']:.1f} ({truth['fov_v']:.1f})"


@case("exif", "ngp predict rows report the orientation")
def _(tmp: Path) -> str:
    folder = tmp / "photos"
    folder.mkdir()
    (folder / "p.jpg").write_bytes(exif_jpeg(render_scene(0, size=(160, 120)).image, 8))
    proc = ngp("predict", folder, "--out", tmp / "r.jsonl")
    row = json.loads((tmp / "r.jsonl").read_text())
    expect(proc.returncode == 0 and row["exif_orientation"] == 8 and row["width"] == 120, str(row)[:200])
    return "exif_orientation 8, 120x160"


# ------------------------------------------------------------------------------------------------- batches


@case("batch", "an image gets in a batch (positions 0 and 3) the answer it gets alone")
def _(tmp: Path) -> str:
    scenes = [torch.from_numpy(render_scene(s, size=(320, 240)).image).permute(2, 0, 1) / 255.0 for s in (1, 2, 3)]
    worst = 0.0
    for weights in ("none", "fsnet"):
        batch = calibrate(torch.stack([scenes[0], scenes[1], scenes[2], scenes[0]]).float(), weights=weights)
        for position, i in enumerate([0, 1, 2, 0]):
            alone = calibrate(scenes[i].float(), weights=weights)
            worst = max(worst, float((batch[position].focal - alone.focal).abs()))
    expect(worst < 1e-2, f"focal differs by {worst} px")
    return f"largest focal difference {worst:.2g} px"


# ----------------------------------------------------------------------------------------------- damaged files


@case("damage", "truncated JPEG with a faked end marker")
def _(tmp: Path) -> str:
    data = jpeg_bytes()
    path = tmp / "cut.jpg"
    path.write_bytes(data[: len(data) // 2] + b"\xff\xd9")
    proc = ngp("calibrate", path)
    line = one_line(proc)
    expect(proc.returncode == 1 and "truncated or its compressed data is corrupt" in line, line)
    return line[-90:]


@case("damage", "corrupt JPEG scan data")
def _(tmp: Path) -> str:
    data = bytearray(jpeg_bytes())
    data[len(data) // 2 : len(data) // 2 + 8] = b"\xff\xd3" * 4
    path = tmp / "corrupt.jpg"
    path.write_bytes(bytes(data))
    proc = ngp("calibrate", path)
    line = one_line(proc)
    expect(proc.returncode == 1 and "corrupt" in line, line)
    return line[-90:]


@case("damage", "valid JPEG with bytes after its end marker is accepted")
def _(tmp: Path) -> str:
    path = tmp / "trailer.jpg"
    path.write_bytes(jpeg_bytes() + bytes(5000))
    proc = ngp("calibrate", path)
    expect(proc.returncode == 0 and proc.stderr == "", proc.stderr[-300:])
    return "calibrated"


@case("damage", "missing, empty, directory, text, truncated PNG, CRC error, tiny image: one line each")
def _(tmp: Path) -> str:
    png = cv2.imencode(".png", np.zeros((64, 64, 3), np.uint8))[1].tobytes()
    crc = bytearray(png)
    crc[len(crc) // 2] ^= 0xFF
    files = {
        "missing.jpg": None,
        "empty.jpg": b"",
        "text.jpg": b"not an image",
        "cut.png": png[: len(png) // 2],
        "crc.png": bytes(crc),
        "tiny.png": cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))[1].tobytes(),
        "nojpeg.jpg": jpeg_bytes()[: len(jpeg_bytes()) // 2],
    }
    for name, data in files.items():
        if data is not None:
            (tmp / name).write_bytes(data)
    (tmp / "dir.jpg").mkdir()
    for name in [*files, "dir.jpg"]:
        proc = ngp("calibrate", tmp / name)
        line = one_line(proc)
        expect(proc.returncode == 1 and name in line and "libpng" not in proc.stderr.split(": ", 2)[1], line)
    return f"{len(files) + 1} files, one line each, no decoder noise"


# ------------------------------------------------------------------------------------------------ outputs


@case("output", "ngp predict --out naming one of the inputs is refused")
def _(tmp: Path) -> str:
    image = scene_png(tmp / "photos" / "a.png")
    before = image.read_bytes()
    proc = ngp("predict", tmp / "photos", "--out", image)
    line = one_line(proc)
    expect(proc.returncode == 1 and image.read_bytes() == before and "one of the input images" in line, line)
    return line[-70:]


@case("output", "an unrelated <out>.rank0 survives ngp predict")
def _(tmp: Path) -> str:
    scene_png(tmp / "photos" / "a.png")
    other = tmp / "r.jsonl.rank0"
    other.write_text("mine")
    proc = ngp("predict", tmp / "photos", "--out", tmp / "r.jsonl")
    expect(proc.returncode == 0 and other.read_text() == "mine", proc.stderr[-200:])
    return "kept"


@case("input", "ngp predict --list naming a device, a pipe, a folder, a missing file and a good image")
def _(tmp: Path) -> str:
    scene_png(tmp / "a.png")
    os.mkfifo(tmp / "pipe")
    (tmp / "folder").mkdir()
    (tmp / "list.txt").write_text("/dev/zero\npipe\nfolder\nmissing.png\na.png\n")
    proc = ngp("predict", "--list", tmp / "list.txt", "--out", tmp / "r.jsonl")
    rows = [json.loads(line) for line in (tmp / "r.jsonl").read_text().splitlines()]
    expect(proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr[-300:])
    expect([("error" in r) for r in rows] == [True, True, True, True, False], str(rows)[:300])
    return "4 error rows, 1 row"


@case("output", "--overlay, rectify -o, render into existing outputs need --force; inputs never overwritten")
def _(tmp: Path) -> str:
    image = scene_png(tmp / "a.png")
    target = tmp / "o.png"
    target.write_bytes(b"keep")
    checks = [
        ngp("calibrate", image, "--overlay", target),
        ngp("rectify", image, "-o", target),
        ngp("calibrate", image, "--overlay", image, "--force"),
    ]
    expect(ngp("render", tmp / "set", "--count", "1", "--size", "64x48").returncode == 0, "render failed")
    checks.append(ngp("render", tmp / "set", "--count", "1", "--size", "64x48", "--seed", "3"))
    for proc in checks:
        one_line(proc)
        expect(proc.returncode == 1, proc.stderr)
    expect(target.read_bytes() == b"keep", "overwritten")
    expect(ngp("calibrate", image, "--overlay", target, "--force").returncode == 0, "--force did not write")
    return "4 refusals, --force writes"


@case("output", "overlay path without an extension")
def _(tmp: Path) -> str:
    proc = ngp("calibrate", scene_png(tmp / "a.png"), "--overlay", tmp / "overlay")
    line = one_line(proc)
    expect(proc.returncode == 1 and ".png" in line, line)
    return line[-80:]


def interrupt(tmp: Path, devices: int) -> str:
    folder, out = tmp / "photos", tmp / "r.jsonl"
    first = scene_png(folder / "s000.png")
    for i in range(1, 200):
        (folder / f"s{i:03d}.png").write_bytes(first.read_bytes())
    command = [sys.executable, "-m", "ngp_kornia.cli", "predict", str(folder), "--out", str(out)]
    proc = subprocess.Popen(
        [*command, "--devices", str(devices)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env(),
        start_new_session=True,
    )
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        partial = list((tmp / ".r.jsonl.ngp-run").glob("*.rows"))
        if sum(p.read_text().count("\n") for p in partial if p.is_file()) >= 2 * devices:
            break
        time.sleep(0.2)
    expect(proc.poll() is None, "ended before the interruption")
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    lines = [line for line in err.splitlines() if line.startswith("ngp")]
    rows = [json.loads(line) for line in out.read_text().splitlines()] if out.exists() else []
    expect(proc.returncode == 130 and len(lines) == 1 and "Traceback" not in err, err[-400:])
    expect(rows and all("focal" in r for r in rows), f"{len(rows)} rows")
    left = sorted(p.name for p in tmp.iterdir())  # the run folder stays for --resume
    expect(left == [".r.jsonl.ngp-run", "photos", "r.jsonl"], str(left))
    return lines[0][:90]


@case("interrupt", "Ctrl+C in ngp predict (one process)")
def _(tmp: Path) -> str:
    return interrupt(tmp, 1)


@case("interrupt", "Ctrl+C in ngp predict --devices 2")
def _(tmp: Path) -> str:
    return interrupt(tmp, 2)


# ------------------------------------------------------------------------------------------------------ weights


@case("weights", "weights full of NaN")
def _(tmp: Path) -> str:
    path = tmp / "nan.pt"
    net = ZSNet(width=8)
    with torch.no_grad():
        for p in net.parameters():
            p.fill_(float("nan"))
    save_network(net, path, net.settings())
    proc = ngp("calibrate", "--weights", path, scene_png(tmp / "a.png"))
    line = weights_usage_error(proc)
    expect("NaN" in line, line)
    return line[-70:]


@case("weights", "two ZSNet files in a list")
def _(tmp: Path) -> str:
    a, b = tmp / "a.pt", tmp / "b.pt"
    for path in (a, b):
        save_network(ZSNet(width=8), path, ZSNet(width=8).settings())
    try:
        calibrate(torch.rand(3, 64, 64), weights=[str(a), str(b)])
    except WeightsError as err:
        return str(err)[-70:]
    raise Failed("accepted")


@case("weights", "random bytes as a weights file: one line, no torch advice")
def _(tmp: Path) -> str:
    path = tmp / "random.pt"
    path.write_bytes(os.urandom(4096))
    proc = ngp("calibrate", "--weights", path, scene_png(tmp / "a.png"))
    line = weights_usage_error(proc)
    expect("weights_only" not in line, line)
    return line[-70:]


@case("weights", "ngp-train export: missing file, random bytes, not a checkpoint of ngp-train")
def _(tmp: Path) -> str:
    (tmp / "r.ckpt").write_bytes(os.urandom(4096))
    torch.save({"epoch": 1}, tmp / "x.ckpt")
    for name in ("none.ckpt", "r.ckpt", "x.ckpt"):
        proc = run(["ngp_kornia.training.command", "export", str(tmp / name), str(tmp / "o.pt")])
        one_line(proc, "ngp-train: error: ")
        expect(proc.returncode == 1, proc.stderr)
    return "3 one-line errors"


# ------------------------------------------------------------------------------------------- settings, tensors


@case("config", "ParserConfig: NaN, 0, negative, working_size=0, num_frames=0, seed 2**70")
def _(tmp: Path) -> str:
    bad = [
        {"fallback_fov": float("nan")},
        {"fallback_fov": 0.0},
        {"top_k": -1},
        {"working_size": 0},
        {"num_frames": 0},
        {"seed": 2**70},
    ]
    for fields in bad:
        try:
            ParserConfig(**fields)
        except ConfigError as err:
            expect(f"ParserConfig.{next(iter(fields))}" in str(err), str(err))
            continue
        raise Failed(f"accepted {fields}")
    proc = ngp("calibrate", "--seed", str(2**70), scene_png(tmp / "a.png"))
    expect(proc.returncode == 1 and "ParserConfig.seed" in one_line(proc), proc.stderr)
    return f"{len(bad)} refused, the CLI's --seed too"


@case("config", "float16 and bfloat16 images")
def _(tmp: Path) -> str:
    image = torch.from_numpy(render_scene(2, size=(320, 240)).image).permute(2, 0, 1).float() / 255
    reference = calibrate(image)
    for dtype in (torch.float16, torch.bfloat16):
        half = calibrate(image.to(dtype))
        expect(half.focal.dtype == dtype and abs(float(half.fov_v) - float(reference.fov_v)) < 1.0, str(half))
    return f"fov_v {float(reference.fov_v):.2f} in float32, the same within 1 deg in both"


@case("config", "NaN segment given to the layer; NaN in padding")
def _(tmp: Path) -> str:
    parser = NeuralGeometricParser()
    segments = torch.tensor([[[[5.0, 5.0], [5.0, 60.0]], [[40.0, 5.0], [42.0, 60.0]], [[0.0, 0.0], [1.0, 1.0]]]])
    mask = torch.tensor([[True, True, False]])
    padded = segments.clone()
    padded[0, 2] = float("nan")
    parser(torch.rand(1, 3, 64, 64), padded, mask)
    segments[0, 0, 0, 0] = float("nan")
    try:
        parser(torch.rand(1, 3, 64, 64), segments, mask)
    except InputError as err:
        return str(err)[:80]
    raise Failed("accepted")


@case("config", "tensors: NaN, wrong shape, 0-255 values, uint8, empty batch")
def _(tmp: Path) -> str:
    bad = [
        torch.full((3, 40, 40), float("nan")),
        torch.rand(4, 40, 40),
        torch.rand(3, 40, 40) * 255,
        torch.zeros(3, 40, 40, dtype=torch.uint8),
        torch.rand(0, 3, 40, 40),
    ]
    for tensor in bad:
        try:
            calibrate(tensor)
        except (NGPError, TypeError):
            continue
        raise Failed(f"accepted {tensor.dtype} {tuple(tensor.shape)}")
    return f"{len(bad)} refused"


@case("cli", "ngp predict on a missing folder, an empty folder, a file")
def _(tmp: Path) -> str:
    (tmp / "empty").mkdir()
    scene_png(tmp / "a.png")
    for target in (tmp / "none", tmp / "empty", tmp / "a.png"):
        proc = ngp("predict", target, "--out", tmp / "r.jsonl")
        one_line(proc)
        expect(proc.returncode == 1, proc.stderr)
    return "3 one-line errors"


@case("cli", "errors derive from NGPError and keep ValueError")
def _(tmp: Path) -> str:
    for cls in (ImageReadError, WeightsError, ConfigError, InputError, ngp_kornia.ManifestError):
        expect(issubclass(cls, NGPError) and issubclass(cls, ValueError), cls.__name__)
    return "ImageReadError, WeightsError, ConfigError, InputError, ManifestError"


def main() -> int:
    global MEMORY_GB
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--memory-gb", type=float, default=MEMORY_GB, help="address-space limit of every command")
    parser.add_argument("--quick", action="store_true", help="skip the Ctrl+C cases (the slowest)")
    args = parser.parse_args()
    MEMORY_GB = args.memory_gb
    print(
        f"memory limit of every command: {MEMORY_GB:g} GB (RLIMIT_AS); torch {torch.__version__}, cv2 {cv2.__version__}"
    )
    print("| # | group | case | result | detail | s |")
    print("|---:|---|---|---|---|---:|")
    failed = 0
    for number, (group, name, fn) in enumerate(CASES, 1):
        if args.quick and group == "interrupt":
            continue
        start = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            try:
                detail, result = fn(Path(tmp)), "pass"
            except Failed as err:
                detail, result = str(err), "FAIL"
            except Exception as err:  # a case that crashes is a failure too, and the rest still run
                detail, result = f"{type(err).__name__}: {err}", "FAIL"
        failed += result == "FAIL"
        detail = " ".join(str(detail).split()).replace("|", "/")
        print(
            f"| {number} | {group} | {name} | {result} | {detail[:140]} | {time.perf_counter() - start:.1f} |",
            flush=True,
        )
    total = len([c for c in CASES if not (args.quick and c[0] == "interrupt")])
    print(f"\n{total - failed} of {total} cases pass")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
