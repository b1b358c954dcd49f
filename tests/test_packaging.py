"""Packaging metadata: the licence as an SPDX string with its text, py.typed and the configs shipped, the extras."""

import re
from pathlib import Path

import pytest

import ngp_kornia

tomllib = pytest.importorskip("tomllib", reason="reading pyproject.toml needs Python 3.11's tomllib")

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_licence_is_an_spdx_string_with_its_full_text():
    project = PYPROJECT["project"]
    assert project["license"] == "Apache-2.0"  # a TOML table here makes setuptools print a deprecation box
    assert project["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text and text.count("\n") > 190
    # SPDX strings need setuptools 77 (PEP 639)
    requires = " ".join(PYPROJECT["build-system"]["requires"])
    version = re.search(r"setuptools>=(\d+)", requires)
    assert version and int(version.group(1)) >= 77


def test_package_data_ships_weights_configs_and_py_typed():
    package = Path(ngp_kornia.__file__).parent
    data = PYPROJECT["tool"]["setuptools"]["package-data"]["ngp_kornia"]
    assert {"weights/*.pt", "configs/*.yaml", "py.typed"} <= set(data)
    assert (package / "py.typed").is_file()
    configs = sorted(p.name for p in (package / "configs").glob("*.yaml"))
    assert configs == [
        "evidence.yaml", "evidence_nyu.yaml", "fsnet.yaml", "fsnet_photos.yaml", "upright.yaml", "upright_lines.yaml",
        "zsnet.yaml", "zsnet_nyu.yaml",
    ]


def test_extras_for_notebooks_plots_and_tensorboard():
    extras = PYPROJECT["project"]["optional-dependencies"]
    assert any(r.startswith("nbmake") for r in extras["notebooks"])
    assert any(r.startswith("matplotlib") for r in extras["notebooks"])
    assert any(r.startswith("matplotlib") for r in extras["plot"])
    assert any(r.startswith("tensorboard") for r in extras["tensorboard"])
    assert any(r.startswith("pycolmap") for r in extras["colmap"])
    # make test installs [test]: it must bring what the notebooks, the plot and the COLMAP tests use
    assert any(r.startswith("ngp-kornia[") and {"notebooks", "plot", "colmap"} <= set(r[11:-1].split(","))
               for r in extras["test"])
