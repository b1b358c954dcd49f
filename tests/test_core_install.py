"""Every command of a core install (``pip install ngp-kornia``, no extras): calibrate, rectify, demo and render work;
predict and ngp-train say which extra to install in one line, and their --help works.

The fast tests hide the extras from a fresh interpreter (tests/core_only.py); the slow one builds a real core-only
virtual environment and runs each command there once."""

import json
import os
import shutil
import subprocess
import sys
import venv
from pathlib import Path

import cv2
import pytest

from ngp_kornia.training.synth.render import render_scene
from tests.core_only import EXTRAS, ROOT, core_env, run_command


@pytest.fixture(scope="module")
def core(tmp_path_factory):
    """(folder to run in, environment without the extras)."""
    root = tmp_path_factory.mktemp("core")
    hide = root / "hide"
    hide.mkdir()
    cv2.imwrite(str(root / "scene.png"), cv2.cvtColor(render_scene(1, (320, 240)).image, cv2.COLOR_RGB2BGR))
    (root / "photos").mkdir()
    shutil.copy(root / "scene.png", root / "photos" / "scene.png")
    return root, core_env(hide)


def test_the_extras_are_hidden(core):
    root, env = core
    code = f"import importlib.util as u; print([n for n in {EXTRAS!r} if u.find_spec(n) is not None])"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=root)
    assert run.stdout.strip() == "[]", run.stderr
    run = subprocess.run([sys.executable, "-c", "import lightning"], capture_output=True, text=True, env=env)
    assert "No module named 'lightning'" in run.stderr


CORE_COMMANDS = [
    ["calibrate", "scene.png", "--overlay", "overlay.png"],
    ["rectify", "scene.png", "-o", "upright.png"],
    ["demo"],
    ["render", "rendered", "--count", "1", "--size", "160x120"],
]


@pytest.mark.parametrize("args", CORE_COMMANDS, ids=[a[0] for a in CORE_COMMANDS])
def test_core_commands_work_without_the_extras(core, args):
    root, env = core
    run = run_command("ngp", args, root, env)
    assert run.returncode == 0 and run.stderr == "", run.stderr[-2000:]
    assert not {"lightning", "jsonargparse"} & set(run.heavy)
    written = {"calibrate": "overlay.png", "rectify": "upright.png", "render": "rendered/000000.png"}.get(args[0])
    if written:
        assert cv2.imread(str(root / written)) is not None
    if args[0] == "calibrate":
        assert json.loads(run.stdout)["image"] == "scene.png"


EXTRA_COMMANDS = [  # (entry, arguments, the extra the message names)
    ("ngp", ["predict", "photos", "--out", "rows.jsonl"], "train"),
    ("ngp_train", ["fit", "--config", "zsnet"], "train"),
    ("ngp_train", ["export", "a.ckpt", "b.pt"], "train"),
    ("ngp_train", ["plot", "logs"], "plot"),
]


@pytest.mark.parametrize(("entry", "args", "extra"), EXTRA_COMMANDS, ids=[a[0] for _, a, _ in EXTRA_COMMANDS])
def test_commands_of_an_extra_say_what_to_install(core, entry, args, extra):
    root, env = core
    run = run_command(entry, args, root, env)
    prefix = "ngp" if entry == "ngp" else "ngp-train"
    assert run.returncode == 1 and run.stdout == ""
    assert run.stderr.startswith(f"{prefix}: error: ") and run.stderr.count("\n") == 1, run.stderr[-2000:]
    assert run.stderr.strip().endswith(f"pip install 'ngp-kornia[{extra}]'")
    assert not (root / "rows.jsonl").exists()


@pytest.mark.parametrize(
    ("entry", "args"), [("ngp", ["predict", "--help"]), ("ngp_train", ["--help"]), ("ngp_train", ["plot", "--help"])]
)
def test_help_of_an_extra_command_works_without_it(core, entry, args):
    root, env = core
    run = run_command(entry, args, root, env)
    assert run.returncode == 0 and run.stdout.startswith("usage: ") and run.stderr == ""


def _wheel_of_torch() -> str:
    """The torch the project's venv holds, as a requirement pip resolves from the local wheels."""
    import torch

    return f"torch=={torch.__version__.split('+')[0]}"


@pytest.mark.slow
def test_a_real_core_only_install_runs_every_command(tmp_path):
    # python -m venv, torch from the local wheel, then this checkout without extras: what a user gets
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    python = env_dir / "bin" / "python"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    pip = [str(python), "-m", "pip", "install", "-q"]
    for requirement in ([_wheel_of_torch()], [str(ROOT)]):
        step = subprocess.run([*pip, *requirement], capture_output=True, text=True, env=env, timeout=1500)
        assert step.returncode == 0, step.stderr[-3000:]
    listed = subprocess.run([str(python), "-m", "pip", "list"], capture_output=True, text=True, env=env).stdout
    assert "lightning" not in listed.lower() and "jsonargparse" not in listed.lower()
    cv2.imwrite(str(tmp_path / "scene.png"), cv2.cvtColor(render_scene(1, (320, 240)).image, cv2.COLOR_RGB2BGR))
    (tmp_path / "photos").mkdir()
    shutil.copy(tmp_path / "scene.png", tmp_path / "photos" / "scene.png")
    bin_dir = env_dir / "bin"
    for args in CORE_COMMANDS:
        run = subprocess.run([str(bin_dir / "ngp"), *args], capture_output=True, text=True, env=env, cwd=tmp_path)
        assert run.returncode == 0 and "Traceback" not in run.stderr, (args, run.stderr[-2000:])
    for command, args, extra in [(c.replace("_", "-"), a, x) for c, a, x in EXTRA_COMMANDS]:
        run = subprocess.run([str(bin_dir / command), *args], capture_output=True, text=True, env=env, cwd=tmp_path)
        assert run.returncode == 1 and run.stderr.count("\n") == 1, (args, run.stderr[-2000:])
        assert run.stderr.strip().endswith(f"pip install 'ngp-kornia[{extra}]'")
    for command in (["ngp", "predict", "--help"], ["ngp-train", "--help"]):
        run = subprocess.run([str(bin_dir / command[0]), *command[1:]], capture_output=True, text=True, env=env)
        assert run.returncode == 0 and run.stdout.startswith("usage: "), run.stderr[-2000:]
    assert Path(tmp_path / "rendered" / "ground_truth.json").is_file()
