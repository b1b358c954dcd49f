"""The notebooks as stored: executed, with their outputs and at least one picture each (so they show where notebooks
are rendered, e.g. on GitHub), of a reasonable size, and naming only things the package has. (CI also executes them
again: ``pytest --nbmake``, among the slow tests.)"""

import dataclasses
import importlib
import json
import re
from pathlib import Path

import pytest

import ngp_kornia
import ngp_kornia.pipeline
from ngp_kornia.pipeline import ParserTrace

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
MAX_BYTES = 1_000_000
#: the first part of a dotted name in the notebooks' text, and what it names: the package's public classes, and the
#: trace the geometry notebook draws (``trace.horizontal_vps``)
HEADS = {name: getattr(ngp_kornia.pipeline, name) for name in ngp_kornia.pipeline.__all__}
HEADS.update({name: getattr(ngp_kornia, name) for name in ngp_kornia.__all__ if not name.startswith("_")})
HEADS["trace"] = ParserTrace


def cells(path: Path) -> list[dict]:
    return json.loads(path.read_text(encoding="utf-8"))["cells"]


def test_there_are_notebooks():
    assert [p.name for p in NOTEBOOKS] == ["01_quickstart.ipynb", "02_geometry.ipynb", "03_training.ipynb"]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_a_notebook_is_stored_executed_with_a_picture(path):
    code = [cell for cell in cells(path) if cell["cell_type"] == "code"]
    assert [cell["execution_count"] for cell in code] == list(range(1, len(code) + 1)), "run it top to bottom"
    outputs = [output for cell in code for output in cell["outputs"]]
    assert not [o for o in outputs if o["output_type"] == "error"]
    assert any("image/png" in o.get("data", {}) for o in outputs), "no picture among the outputs"
    assert path.stat().st_size < MAX_BYTES, f"{path.name}: {path.stat().st_size} bytes; keep the pictures small"


def resolve(name: str) -> bool | None:
    """Whether a dotted name of the text exists (None: not one of the package's, so not checked)."""
    head, *rest = name.split(".")
    if head == "ngp_kornia":
        thing, done = ngp_kornia, ["ngp_kornia"]
        for part in rest:
            done.append(part)
            if not hasattr(thing, part):
                try:
                    importlib.import_module(".".join(done))
                except ImportError:
                    return False
            thing = getattr(thing, part, None)
            if thing is None:
                return False
        return True
    if head not in HEADS:
        return None
    thing = HEADS[head]
    for part in rest:
        if dataclasses.is_dataclass(thing) and part in {f.name for f in dataclasses.fields(thing)}:
            return True  # a field (whose value the class may not hold)
        if not hasattr(thing, part):
            return False
        thing = getattr(thing, part)
    return True


def test_the_name_check_finds_a_stale_name():
    assert resolve("ngp_kornia.pipeline.horizon") and resolve("HorizonSettings.refine")
    assert resolve("trace.horizontal_vps") and resolve("ngp_kornia.viz.draw_calibration")
    assert resolve("ParserConfig.refine_horizon") is False and resolve("ngp_kornia.pipeline.refine") is False
    assert resolve("cal.K") is None


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_every_name_the_text_gives_exists(path):
    text = "\n".join("".join(cell["source"]) for cell in cells(path) if cell["cell_type"] == "markdown")
    names = {m.removesuffix("()") for m in re.findall(r"`([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)+(?:\(\))?)`", text)}
    stale = sorted(name for name in names if resolve(name) is False)
    assert not stale, f"{path.name} names what the package does not have: {stale}"
