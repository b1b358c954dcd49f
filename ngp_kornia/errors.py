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
    "NGPWarning",
    "OutputError",
    "WeightsError",
    "shown",
]

#: the longest ``repr`` a message quotes; a longer one (a network, a large array) is named by its type
_SHOWN_CHARS = 80


def shown(value: object) -> str:
    """How an error message quotes a value a caller passed: its ``repr`` where that is one short line, else its type
    in angle brackets (with the shape of an array or tensor), so that a message stays one line whatever was passed.

    Example:
        >>> shown(0.5), shown("x" * 200)
        ('0.5', '<str>')
        >>> import numpy as np
        >>> shown(np.zeros((480, 640)))
        '<ndarray of shape (480, 640)>'
    """
    text = repr(value)
    if len(text) <= _SHOWN_CHARS and "\n" not in text:
        return text
    shape = getattr(value, "shape", None)
    of_shape = f" of shape {tuple(shape)}" if isinstance(shape, tuple) else ""  # torch.Size is a tuple
    return f"<{type(value).__name__}{of_shape}>"


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


class NGPWarning(UserWarning):
    """A result that is less than what was asked for, said once (``warnings.warn``): a camera to be shared by photos
    of which fewer than two have lines, so nothing is shared. The command-line tools print it as one line,
    ``ngp: warning: <message>``."""
