"""Command-line options built from the pipeline's settings: one ``--stage.field`` option per field of
:class:`~ngp_kornia.pipeline.settings.ParserConfig` (``--segments.working_size 640``, ``--horizon.refine false``),
its help text the field's docstring and its checks the field's own. Imports nothing heavy, so ``--help`` stays fast.

Example:
    >>> import argparse
    >>> parser = argparse.ArgumentParser()
    >>> add_setting_options(parser)
    >>> config_from_args(parser.parse_args(["--segments.working_size", "640"])).segments.working_size
    640
"""

from __future__ import annotations

import argparse

from ngp_kornia.pipeline.settings import ParserConfig, setting_fields

__all__ = ["add_setting_options", "config_from_args", "short_usage", "subcommand"]

#: the namespace attribute prefix of the settings' options
_PREFIX = "setting:"


def _flag(text: str) -> bool:
    words = {"true": True, "yes": True, "1": True, "false": False, "no": False, "0": False}
    if text.lower() not in words:
        raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
    return words[text.lower()]


def add_setting_options(command: argparse.ArgumentParser) -> None:
    """Add the ``--stage.field`` options of every pipeline setting to ``command``, in one group per stage."""
    groups: dict[str, argparse._ArgumentGroup] = {}
    for stage, f, doc in setting_fields():
        if stage not in groups:
            groups[stage] = command.add_argument_group(f"pipeline settings: {stage}")
        text = f"{doc} (default: {f.default})".replace("%", "%%")  # argparse formats help with %
        kwargs: dict = {"dest": f"{_PREFIX}{stage}.{f.name}", "default": None, "help": text}
        if "flag" in f.metadata:
            kwargs.update(type=_flag, metavar="{true,false}")
        elif "choices" in f.metadata:
            kwargs.update(choices=f.metadata["choices"])
        elif "tuple" in f.metadata:
            count = f.metadata["tuple"][0]
            kwargs.update(type=float, nargs=count or "+", metavar="X")
        else:
            integer = f.type in ("int", int)
            kwargs.update(type=int if integer else float, metavar="N" if integer else "X")
        groups[stage].add_argument(f"--{stage}.{f.name}", **kwargs)


def config_from_args(args: argparse.Namespace) -> ParserConfig:
    """The :class:`ParserConfig` of the settings given on the command line (the defaults for the others).

    Raises:
        ConfigError: a value out of its range; the message names the setting.
    """
    given = {
        key[len(_PREFIX) :]: value
        for key, value in vars(args).items()
        if key.startswith(_PREFIX) and value is not None
    }
    return ParserConfig().replace(**given) if given else ParserConfig()


def subcommand(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    """The parser of subcommand ``name``, whose usage errors name it (``ngp calibrate: error: ...``)."""
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[name]


def short_usage(command: argparse.ArgumentParser) -> str:
    """``ngp calibrate [options] images ...``: argparse's own usage lists every setting (forty lines), and prints it
    before every usage error; ``--help`` lists the options."""
    names = [a.dest + (" ..." if a.nargs in ("*", "+") else "") for a in command._actions if not a.option_strings]
    return " ".join(["%(prog)s [options]", *names])
