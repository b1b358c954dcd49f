"""Entry points of the ``ngp`` and ``ngp-train`` commands.

Their modules import torch, OpenCV and Lightning, which takes a few seconds. Ctrl+C in that time ends the command at
once with a one-line message and exit status 130 (as shells report an interrupt); nothing has been read or written
yet. It is not raised as ``KeyboardInterrupt`` there: some of those libraries catch every exception while they import,
and a half-imported module then fails later with an unrelated error. Once imported, the command handles Ctrl+C
itself (``ngp predict`` keeps the rows it finished).
"""

from __future__ import annotations

import importlib
import os
import signal
import sys


def _run(command: str, modules: list[str]) -> int:
    def stop(signum, frame) -> None:
        print(f"{command}: interrupted", file=sys.stderr, flush=True)
        os._exit(130)

    previous = signal.signal(signal.SIGINT, stop)
    try:
        loaded = [importlib.import_module(name) for name in modules]  # the command's own module first
        main = loaded[0].main
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        return main()
    except KeyboardInterrupt:
        print(f"{command}: interrupted", file=sys.stderr)
        return 130


def ngp() -> int:
    """The ``ngp`` command (:func:`ngp_kornia.cli.main`), with the modules its subcommand needs imported first."""
    later = {"predict": ["ngp_kornia.predict"]}.get(sys.argv[1] if len(sys.argv) > 1 else "", [])
    return _run("ngp", ["ngp_kornia.cli", "ngp_kornia.api", *later])


def ngp_train() -> int:
    """The ``ngp-train`` command (:func:`ngp_kornia.training.command.main`)."""
    return _run("ngp-train", ["ngp_kornia.training.command"])
