"""Suggestions for a mistyped name: the names meant, as an error message offers them (``did you mean ...?``).

Example:
    >>> did_you_mean("refin", ["horizon.refine", "horizon.margin", "polish.enabled"])
    'did you mean horizon.refine? '
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence

__all__ = ["did_you_mean", "either"]


def either(names: Sequence[str]) -> str:
    """``a``, ``a or b``, ``a, b or c``.

    Example:
        >>> either(["evidence.enabled", "polish.enabled", "upright.enabled"])
        'evidence.enabled, polish.enabled or upright.enabled'
    """
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


def did_you_mean(word: str, names: Sequence[str], cutoff: float = 0.85) -> str:
    """``"did you mean <the closest names>? "``, or ``""`` where none is close. A word without a dot is also
    compared with the last part of dotted names (``refin`` finds ``horizon.refine``)."""
    close = difflib.get_close_matches(word, names, n=2, cutoff=cutoff)
    if "." not in word:
        close += [name for name in names if difflib.get_close_matches(word, [name.rsplit(".", 1)[-1]], 1, 0.8)]
    close = list(dict.fromkeys(close))[:3]
    return f"did you mean {either(close)}? " if close else ""
