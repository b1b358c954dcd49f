"""The core (calibrate, geometry, models, the ngp command but predict) runs without the optional dependencies of the
``train`` extra; what needs them says which extra to install."""

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# a Python run in which lightning and jsonargparse cannot be imported, as after `pip install ngp-kornia`
BLOCK = textwrap.dedent(
    """
    import sys

    class Block:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("lightning", "jsonargparse", "pytorch_lightning", "tensorboard"):
                raise ModuleNotFoundError(f"No module named {name!r}")

    sys.meta_path.insert(0, Block())
    """
)


def _run(code: str, tmp_path: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", BLOCK + textwrap.dedent(code)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={"PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"},
        timeout=300,
    )


def test_the_core_runs_without_the_train_extra(tmp_path):
    out = _run(
        """
        import numpy as np
        import ngp_kornia
        from ngp_kornia import geometry, metrics, viz
        from ngp_kornia.pipeline import candidates
        from ngp_kornia.cli import main
        from ngp_kornia.training.synth.render import render_scene
        from ngp_kornia.nets import FSNet, ZSNet
        from ngp_kornia.pipeline import NeuralGeometricParser

        image = render_scene(2, (160, 120)).image
        print(ngp_kornia.calibrate(image, weights="full").valid.item())
        import cv2
        cv2.imwrite("scene.png", image[..., ::-1])
        assert main(["calibrate", "scene.png", "--overlay", "overlay.png"]) == 0
        assert "lightning" not in sys.modules and "jsonargparse" not in sys.modules
        """,
        tmp_path,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[0] == "True" and (tmp_path / "overlay.png").exists()


def test_predict_and_training_name_the_extra_to_install(tmp_path):
    out = _run(
        """
        from ngp_kornia.cli import main
        from ngp_kornia.training import command
        try:
            import ngp_kornia.predict
        except ImportError as err:
            print(err)
        print(main(["predict", ".", "--out", "rows.jsonl"]), command.main(["fit", "--config", "zsnet"]))
        """,
        tmp_path,
    )
    lines = out.stdout.splitlines()
    assert len(lines) == 2 and "pip install 'ngp-kornia[train]'" in lines[0] and lines[1] == "1 1", out.stdout
    err = out.stderr.strip().splitlines()
    assert len(err) == 2 and err[0].startswith("ngp: error: ngp predict needs lightning")
    assert err[1].startswith("ngp-train: error: training needs lightning and jsonargparse")
    assert all(line.endswith("pip install 'ngp-kornia[train]'") for line in err)


def test_loading_the_shipped_networks_stays_light(tmp_path):
    # the shapes of a weights file are checked on the meta device; drawing random weights there imports
    # torch._dynamo, which added 1-2 s to every process that loads a network
    out = _run(
        """
        from ngp_kornia.api import load_parser
        parser = load_parser("full")
        assert parser.zsnet is not None and parser.fsnet is not None
        print("torch._dynamo" in sys.modules)
        """,
        tmp_path,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False"]
