"""Entry points of the ``ngp`` and ``ngp-train`` commands.

The command line is parsed and checked first, importing nothing heavy: ``--help``, ``--version`` and wrong arguments
are answered at once. Then the command's modules are imported: torch, OpenCV and Lightning, which takes a few
seconds. Ctrl+C in that time ends the command at once with a one-line message and exit status 130 (as shells report
an interrupt); nothing has been read or written yet. It is not raised as ``KeyboardInterrupt`` there: some of those
libraries catch every exception while they import, and a half-imported module then fails later with an unrelated
error. Once imported, the command handles Ctrl+C itself (``ngp predict`` keeps the rows it finished).
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
from collections.abc import Callable

__all__ = ["ngp", "ngp_train"]


def _run(command: str, modules: list[str], main: Callable[[], int]) -> int:
    def stop(signum, frame) -> None:
        print(f"{command}: interrupted", file=sys.stderr, flush=True)
        os._exit(130)

    previous = signal.signal(signal.SIGINT, stop)
    try:
        for name in modules:
            importlib.import_module(name)
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        return main()
    except KeyboardInterrupt:
        print(f"{command}: interrupted", file=sys.stderr)
        return 130


def ngp() -> int:
    """The ``ngp`` command (:func:`ngp_kornia.cli.parse`, then :func:`ngp_kornia.cli.run`)."""
    from ngp_kornia import cli

    args = cli.parse()
    if isinstance(args, int):
        return args
    later = {"predict": ["ngp_kornia.predict"]}.get(args.command, [])
    return _run("ngp", ["ngp_kornia.api", *later], lambda: cli.run(args))


def ngp_train() -> int:
    """The ``ngp-train`` command (:func:`ngp_kornia.training.command.parse`, then
    :func:`ngp_kornia.training.command.run`)."""
    from ngp_kornia.training import command

    args = command.parse()
    if isinstance(args, int):
        return args
    return _run("ngp-train", command.modules(args), lambda: command.run(args))
