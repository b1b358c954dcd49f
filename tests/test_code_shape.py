"""The shape of the code: no function or method in the package or the benchmarks is longer than 60 lines (its
signature, docstring and body), so each one can be read on one screen."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHECKED = ("ngp_kornia", "benchmarks")
MAX_LINES = 60


def long_functions(folder: Path, limit: int = MAX_LINES) -> list[str]:
    """``path:line name (n lines)`` of every function or method in the folder's Python files longer than limit."""
    found = []
    for path in sorted(folder.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > limit:
                    name = (Path(folder.name) / path.relative_to(folder)).as_posix()
                    found.append(f"{name}:{node.lineno} {node.name} ({lines} lines)")
    return found


@pytest.mark.parametrize("folder", CHECKED)
def test_no_function_over_60_lines(folder):
    assert (ROOT / folder).is_dir()
    too_long = long_functions(ROOT / folder)
    assert not too_long, "split these functions (at most 60 lines each):\n" + "\n".join(too_long)


def test_the_check_finds_a_long_function(tmp_path):
    body = "\n".join(f"        x{i} = {i}" for i in range(60))
    (tmp_path / "m.py").write_text(f"def short():\n    return 1\n\n\nclass A:\n    def long(self):\n{body}\n")
    assert long_functions(tmp_path) == [f"{tmp_path.name}/m.py:6 long (61 lines)"]
