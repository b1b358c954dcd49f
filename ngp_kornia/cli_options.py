"""Command-line options built from the pipeline's settings: one ``--stage.field`` option per field of
:class:`~ngp_kornia.pipeline.settings.ParserConfig` (``--segments.working_size 640``, ``--horizon.refine false``),
its help text the field's docstring in plain words and its checks the field's own. ``--help`` leaves them out (a
command's everyday options fit a screen), ``--help-all`` lists them. Imports nothing heavy, so ``--help`` stays fast.

Example:
    >>> import argparse
    >>> parser = argparse.ArgumentParser()
    >>> add_setting_options(parser)
    >>> config_from_args(parser.parse_args(["--segments.working_size", "640"])).segments.working_size
    640
"""

from __future__ import annotations

import argparse
import difflib
import re

from ngp_kornia.pipeline.settings import ParserConfig, setting_fields

__all__ = [
    "HelpAllAction",
    "add_setting_options",
    "closest_option",
    "config_from_args",
    "plain_words",
    "settings_from_args",
    "short_usage",
    "subcommand",
]

#: the namespace attribute prefix of the settings' options
_PREFIX = "setting:"


def _flag(text: str) -> bool:
    words = {"true": True, "yes": True, "1": True, "false": False, "no": False, "0": False}
    if text.lower() not in words:
        raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
    return words[text.lower()]


def plain_words(doc: str) -> str:
    """A docstring's text for a ``--help``: without reStructuredText markup (a role's target becomes its last name)
    and without the paper's equation references.

    Example:
        >>> plain_words("drop them (every weight set of :func:`ngp_kornia.calibrate`); ``s_vh`` alone (Eq. 22)")
        'drop them (every weight set of calibrate); s_vh alone'
    """
    text = re.sub(r":\w+:`~?([\w.]+)`", lambda m: m.group(1).rsplit(".", 1)[-1], doc)
    text = re.sub(r"``([^`]*)``", r"\1", text)
    text = re.sub(r"\s*\([^()]*\bEqs?\.[^()]*\)", "", text)  # "(Eq. 3)", "(the paper's |L_z|, Eq. 3)"
    return re.sub(r"\s*\bEqs?\. ?[\d-]+", "", text)


def add_setting_options(command: argparse.ArgumentParser) -> None:
    """Add the ``--stage.field`` options of every pipeline setting to ``command``, in one group per stage, hidden
    from ``--help`` and listed by ``--help-all`` (:class:`HelpAllAction`, added here too)."""
    command.add_argument("--help-all", action=HelpAllAction, help="also list every pipeline setting")
    groups: dict[str, argparse._ArgumentGroup] = {}
    for stage, f, doc in setting_fields():
        if stage not in groups:
            groups[stage] = command.add_argument_group(f"pipeline settings: {stage}")
        text = f"{plain_words(doc)} (default: {f.default})".replace("%", "%%")  # argparse formats help with %
        kwargs: dict = {"dest": f"{_PREFIX}{stage}.{f.name}", "default": None, "help": argparse.SUPPRESS}
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
        action = groups[stage].add_argument(f"--{stage}.{f.name}", **kwargs)
        action.full_help = text  # what --help-all shows


class HelpAllAction(argparse.Action):
    """``--help-all``: the command's help with every option, the pipeline settings that ``--help`` leaves out too."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest, nargs=0, default=default, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        for action in parser._actions:
            if getattr(action, "full_help", None) is not None:
                action.help = action.full_help
        parser.print_help()
        parser.exit()


def closest_option(command: argparse.ArgumentParser, word: str) -> str | None:
    """The option of ``command`` closest to a mistyped one (``--focla``: ``--focal``), or None.

    Example:
        >>> parser = argparse.ArgumentParser()
        >>> _ = parser.add_argument("--focal"), parser.add_argument("--fov")
        >>> closest_option(parser, "--focla")
        '--focal'
    """
    name = word.split("=", 1)[0]
    options = [option for action in command._actions for option in action.option_strings if option.startswith("--")]
    found = difflib.get_close_matches(name, options, n=1, cutoff=0.6)
    return found[0] if found else None


def settings_from_args(args: argparse.Namespace) -> dict:
    """The settings given on the command line, as the mapping ``calibrate(config=...)`` takes (``"stage.field"``
    -> value): the weight set's settings for the others."""
    return {key[len(_PREFIX) :]: value for key, value in vars(args).items()
            if key.startswith(_PREFIX) and value is not None}


def config_from_args(args: argparse.Namespace) -> ParserConfig:
    """The :class:`ParserConfig` of the settings given on the command line (the defaults for the others).

    Raises:
        ConfigError: a value out of its range; the message names the setting.
    """
    given = settings_from_args(args)
    return ParserConfig().replace(**given) if given else ParserConfig()


def subcommand(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    """The parser of subcommand ``name``, whose usage errors name it (``ngp calibrate: error: ...``)."""
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[name]


def short_usage(command: argparse.ArgumentParser) -> str:
    """``ngp calibrate [options] images ...``: argparse's own usage lists every setting (forty lines), and prints it
    before every usage error; ``--help`` lists the options."""
    shown = {"*": "{} ...", "+": "{} ...", "?": "[{}]"}  # several, or none (ngp predict: a folder or --list)
    names = [shown.get(a.nargs, "{}").format(a.dest) for a in command._actions if not a.option_strings]
    return " ".join(["%(prog)s [options]", *names])
