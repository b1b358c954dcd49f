"""A Python run that looks like a core install (``pip install ngp-kornia``, no extras): a ``sitecustomize`` on
PYTHONPATH hides the extras' top-level modules from every finder, so ``import lightning`` fails and
``importlib.util.find_spec("lightning")`` is None, as where the package is not installed."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: the top-level modules of the extras: train (lightning, jsonargparse), plot and notebooks (matplotlib),
#: tensorboard, colmap (pycolmap)
EXTRAS = ("lightning", "pytorch_lightning", "lightning_fabric", "jsonargparse", "matplotlib", "tensorboard", "pycolmap")

SITECUSTOMIZE = textwrap.dedent(
    """
    import sys

    HIDDEN = {hidden!r}


    class Hide:
        # wraps a finder: finds nothing of the hidden modules, everything else as before
        def __init__(self, finder):
            self.finder = finder

        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in HIDDEN:
                return None
            find = getattr(self.finder, "find_spec", None)
            return None if find is None else find(name, path, target)

        def __getattr__(self, name):
            return getattr(self.finder, name)


    sys.meta_path[:] = [Hide(finder) for finder in sys.meta_path]
    """
)


def core_env(folder: Path) -> dict:
    """An environment for a subprocess in which the extras are not installed (``sitecustomize.py`` goes in
    ``folder``); the package is this checkout's."""
    (folder / "sitecustomize.py").write_text(SITECUSTOMIZE.format(hidden=EXTRAS))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONSTARTUP")}
    env.update(PYTHONPATH=f"{folder}{os.pathsep}{ROOT}", OMP_NUM_THREADS="1")
    return env


#: runs an entry point as its console script does, then writes which heavy modules were imported to HEAVY_FILE
LAUNCH = textwrap.dedent(
    """
    import os, sys
    entry = sys.argv.pop(1)
    sys.argv[0] = entry.replace("_", "-")
    from ngp_kornia import _launch
    try:
        code = getattr(_launch, entry)()
    except SystemExit as stop:
        code = stop.code
    finally:
        heavy = [m for m in ("torch", "lightning", "cv2", "kornia", "numpy", "jsonargparse") if m in sys.modules]
        with open(os.environ["HEAVY_FILE"], "w") as out:
            out.write(" ".join(heavy))
    sys.exit(code)
    """
)


def run_command(entry: str, args: list[str], cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    """Run ``ngp`` (entry ``"ngp"``) or ``ngp-train`` (``"ngp_train"``) with ``args`` in a fresh interpreter; the
    result's ``heavy`` lists the heavy modules it had imported when it ended."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"} if env is None else dict(env)
    env["HEAVY_FILE"] = str(cwd / ".heavy")
    run = subprocess.run(
        [sys.executable, "-c", LAUNCH, entry, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=600
    )
    run.heavy = (cwd / ".heavy").read_text().split()
    return run
