"""The package's exceptions: one base class, :class:`NGPError`, and one subclass per kind of bad input.

Every subclass is also a :class:`ValueError`, as the errors it replaces were, so ``except ValueError`` keeps working.
The command-line tools catch :class:`NGPError` (and kornia's check errors, :class:`kornia.core.exceptions.BaseError`)
and print one line, ``ngp: error: <message>``.

Example:
    >>> from ngp_kornia.errors import ImageReadError, NGPError
    >>> issubclass(ImageReadError, NGPError) and issubclass(ImageReadError, ValueError)
    True
"""

from __future__ import annotations

__all__ = [
    "CheckpointError",
    "ConfigError",
    "ImageReadError",
    "InputError",
    "ManifestError",
    "NGPError",
    "OutputError",
    "WeightsError",
]


class NGPError(Exception):
    """Base of every error ngp-kornia raises on purpose; the message names the input, the problem and the fix."""


class ImageReadError(NGPError, ValueError):
    """An input image that cannot be calibrated (missing, unreadable, corrupt, too small or too large)."""


class InputError(NGPError, ValueError):
    """A tensor given to a module that it cannot use (shapes that do not match, NaN where values are needed)."""


class WeightsError(NGPError, ValueError):
    """A weights file that is missing, unreadable, unsafe, or does not match the network it should hold."""


class CheckpointError(NGPError, ValueError):
    """A training checkpoint that is missing, unreadable, or was not written by ``ngp-train``."""


class ManifestError(NGPError, ValueError):
    """A malformed CSV manifest: the message names the file, the line and the column."""


class ConfigError(NGPError, ValueError):
    """A setting out of range (``ParserConfig`` fields, command-line options); the message names the field."""


class OutputError(NGPError, ValueError):
    """An output path that would overwrite an input or an existing file, or that cannot be written."""
