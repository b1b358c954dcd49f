"""Build the API reference from the docstrings with pdoc: ``python docs/build_api.py [OUTPUT]`` (``make docs``).

Every public module of the package gets a page (``ngp_kornia`` and its rooms, and each public module inside them,
names without a leading underscore), in OUTPUT (default ``docs/api``; open ``index.html``). Docstrings are read as
Google style. A warning from pdoc fails the build: a module that does not import, an ``__all__`` name that does not
exist, a docstring pdoc cannot read. (pdoc cannot evaluate the string annotations of a NamedTuple re-exported by a
room's ``__init__``; those warnings are about pdoc's reach, not the docstrings, and are not counted.)
"""

from __future__ import annotations

import pkgutil
import sys
import warnings
from pathlib import Path

#: pdoc warnings that say nothing about the docstrings (see the module docstring); the second: a room that
#: re-exports a function named as its module (``geometry.rectify``) makes pdoc meet that module twice
IGNORED = ("Error parsing type annotation", "The module specification")


def public_modules(package: str = "ngp_kornia") -> list[str]:
    """The package and every module inside it whose dotted name has no part starting with an underscore."""
    root = __import__(package)
    names = [package]
    for info in pkgutil.walk_packages(root.__path__, prefix=f"{package}."):
        if not any(part.startswith("_") for part in info.name.split(".")):
            names.append(info.name)
    return names


def build(output: Path) -> list[str]:
    """Write the reference to ``output``; returns the warnings that count (empty when the build is clean)."""
    import pdoc
    import pdoc.render

    pdoc.render.configure(docformat="google", footer_text="ngp-kornia")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pdoc.pdoc(*public_modules(), output_directory=output)
    return [
        f"{w.category.__name__}: {w.message}"
        for w in caught
        if issubclass(w.category, UserWarning) and not str(w.message).startswith(IGNORED)
    ]


def main(argv: list[str]) -> int:
    output = Path(argv[0] if argv else "docs/api")
    problems = build(output)
    pages = sorted(output.rglob("*.html"))
    for problem in problems:
        print(f"docs: {problem}", file=sys.stderr)
    if problems:
        print(f"docs: {len(problems)} pdoc warning(s): fix the docstrings or modules above", file=sys.stderr)
        return 1
    print(f"docs: {len(pages)} pages in {output} (open {output / 'index.html'})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
