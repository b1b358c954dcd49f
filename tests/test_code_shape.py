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


# --- the rooms: file sizes, private names, import circles, one-way dependencies -------------------------------

MAX_MODULE_LINES = 500
#: room -> the rooms it must not import (DESIGN: geometry knows nothing of nets or pipeline; nets know geometry;
#: the pipeline knows geometry and nets; training knows nets, pipeline and data; nothing below imports the top)
FORBIDDEN = {
    "geometry": {"nets", "pipeline", "training", "evaluation", "data", "api", "cli", "predict", "viz"},
    "nets": {"pipeline", "training", "evaluation", "api", "cli", "predict", "viz"},
    "pipeline": {"training", "evaluation", "api", "cli", "predict", "viz"},
    "data": {"nets", "pipeline", "training", "evaluation", "api", "cli", "predict"},
    "training": {"evaluation", "cli", "predict"},
}


def _modules() -> dict[str, Path]:
    package = ROOT / "ngp_kornia"
    out = {}
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _imports(path: Path, module_level_only: bool = True) -> list[tuple[str, list[str]]]:
    """(module, names) of every ``ngp_kornia`` import; module-level ones only (not under TYPE_CHECKING, not in a
    function) when ``module_level_only``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    nodes = tree.body if module_level_only else list(ast.walk(tree))
    found = []
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("ngp_kornia"):
            found.append((node.module, [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            found += [(a.name, []) for a in node.names if a.name.startswith("ngp_kornia")]
    return found


def test_no_package_module_over_500_lines():
    long = [f"{m} ({n} lines)" for m, p in _modules().items() if (n := len(p.read_text().splitlines())) > 500]
    assert not long, "split these modules (at most 500 lines each):\n" + "\n".join(long)


def test_no_module_imports_a_private_name_of_another():
    found = []
    for folder in ("ngp_kornia", "tests", "benchmarks"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for module, names in _imports(path, module_level_only=False):
                private = [n for n in names if n.startswith("_") and not n.startswith("__")]
                found += [f"{path.relative_to(ROOT)}: {module}.{n}" for n in private]
    assert not found, "private names imported across modules:\n" + "\n".join(found)


def test_no_import_circle_between_package_modules():
    modules = _modules()
    graph = {m: {target for target, _ in _imports(p) if target in modules and target != m} for m, p in modules.items()}
    for m, p in modules.items():  # ``from package import module`` imports the module too
        for target, names in _imports(p):
            graph[m] |= {f"{target}.{n}" for n in names if f"{target}.{n}" in modules}
    state: dict[str, int] = {}

    def visit(m: str, stack: list[str]) -> list[str] | None:
        state[m] = 1
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return [*stack, m, n]
            if n not in state and (circle := visit(n, [*stack, m])):
                return circle
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            circle = visit(m, [])
            assert circle is None, "import circle: " + " -> ".join(circle)


def test_rooms_talk_one_way():
    found = []
    for module, path in _modules().items():
        room = module.split(".")[1] if "." in module else ""
        for target, _ in _imports(path, module_level_only=False):
            other = target.split(".")[1] if "." in target else ""
            if other in FORBIDDEN.get(room, ()):
                found.append(f"{module} imports {target}")
    assert not found, "imports against the rooms' direction:\n" + "\n".join(found)


def test_every_package_module_has_all_and_no_two_share_a_name():
    modules = _modules()
    missing = [m for m, p in modules.items() if "__all__" not in p.read_text() and not m.endswith("__main__")]
    assert not missing, "modules without __all__: " + ", ".join(missing)
    names = [p.stem for p in modules.values() if p.stem not in ("__init__", "__main__")]
    assert len(names) == len(set(names)), sorted({n for n in names if names.count(n) > 1})
