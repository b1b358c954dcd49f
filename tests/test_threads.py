"""The thread policy: a call runs on one torch thread by default, the caller's setting survives every call (also a
failing one), nothing else of the process changes, and the answer does not depend on the thread count of the
caller's environment."""

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.io import ImageError
from ngp_kornia.pipeline.frame_search import FrameSearch
from ngp_kornia.threads import ENV_VAR, pipeline_threads, resolve_num_threads
from ngp_kornia.training.synth.render import render_scene


@pytest.fixture
def caller_threads():
    """The caller runs with 3 torch threads and 3 OpenCV threads; restored after the test."""
    before = torch.get_num_threads(), cv2.getNumThreads()
    torch.set_num_threads(3)
    cv2.setNumThreads(3)
    yield 3
    torch.set_num_threads(before[0])
    cv2.setNumThreads(before[1])


def test_resolve_default_env_and_explicit(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert resolve_num_threads() == 1
    monkeypatch.setenv(ENV_VAR, "4")
    assert resolve_num_threads() == 4
    assert resolve_num_threads(2) == 2  # an explicit count wins over the environment
    assert resolve_num_threads(0) == 0


@pytest.mark.parametrize("value, message", [("two", "is not a thread count"), ("-1", "is not a thread count")])
def test_resolve_bad_env_names_the_variable(monkeypatch, value, message):
    monkeypatch.setenv(ENV_VAR, value)
    with pytest.raises(ValueError, match=message) as err:
        resolve_num_threads()
    assert ENV_VAR in str(err.value)


def test_resolve_bad_count():
    with pytest.raises(ValueError, match="num_threads=-2"):
        resolve_num_threads(-2)


def test_scope_sets_and_restores_also_on_error(caller_threads, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    with pipeline_threads() as n:
        assert n == 1 and torch.get_num_threads() == 1 and cv2.getNumThreads() == caller_threads  # OpenCV untouched
    assert torch.get_num_threads() == caller_threads and cv2.getNumThreads() == caller_threads
    with pytest.raises(RuntimeError, match="inside"), pipeline_threads(2):
        assert torch.get_num_threads() == 2
        raise RuntimeError("inside")
    assert torch.get_num_threads() == caller_threads and cv2.getNumThreads() == caller_threads


def test_zero_leaves_the_caller_alone(caller_threads):
    with pipeline_threads(0) as n:
        assert n == caller_threads and torch.get_num_threads() == caller_threads
    assert torch.get_num_threads() == caller_threads


def test_nested_scopes_restore_each_level(caller_threads):
    with pipeline_threads(1):
        with pipeline_threads(2):
            assert torch.get_num_threads() == 2
        assert torch.get_num_threads() == 1  # the inner exit restores the outer scope's count
    assert torch.get_num_threads() == caller_threads


def test_a_call_changes_no_other_threads_count(caller_threads):
    # torch's thread count belongs to each thread (OpenMP): a call on one thread leaves another thread's alone
    inside, outside = threading.Event(), threading.Event()
    seen = []

    def call():
        with pipeline_threads(1):
            inside.set()
            outside.wait(10)

    worker = threading.Thread(target=call)
    worker.start()
    inside.wait(10)
    seen.append(torch.get_num_threads())
    outside.set()
    worker.join(20)
    assert seen == [caller_threads] and cv2.getNumThreads() == caller_threads


def test_calibrate_keeps_the_callers_thread_count(caller_threads, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    seen = []
    original = FrameSearch.candidates

    def spy(self, *args, **kwargs):
        seen.append(torch.get_num_threads())
        return original(self, *args, **kwargs)

    monkeypatch.setattr(FrameSearch, "candidates", spy)
    image = render_scene(1, size=(160, 120)).image
    calibrate(image)
    assert seen == [1] and torch.get_num_threads() == caller_threads
    calibrate(image, num_threads=2)
    assert seen[-1] == 2 and torch.get_num_threads() == caller_threads
    calibrate(image, num_threads=0)
    assert seen[-1] == caller_threads and torch.get_num_threads() == caller_threads


def test_calibrate_restores_after_an_exception_inside(caller_threads, monkeypatch):
    def fail(self, *args, **kwargs):
        assert torch.get_num_threads() == 1
        raise RuntimeError("failed inside the parser")

    monkeypatch.setattr(FrameSearch, "candidates", fail)
    with pytest.raises(RuntimeError, match="inside the parser"):
        calibrate(render_scene(1, size=(160, 120)).image)
    assert torch.get_num_threads() == caller_threads and cv2.getNumThreads() == caller_threads
    with pytest.raises(ImageError):  # a bad input fails inside the scope too
        calibrate(torch.full((3, 64, 64), float("nan")))
    assert torch.get_num_threads() == caller_threads


_CHILD = """
import json, sys
import cv2
from ngp_kornia import calibrate
rows = [calibrate(str(p)).to_dict() for p in sorted(__import__("pathlib").Path(sys.argv[1]).glob("*.png"))]
print(json.dumps(rows))
"""


def _child_rows(folder: Path, omp: str) -> str:
    env = {**os.environ, "OMP_NUM_THREADS": omp, "MKL_NUM_THREADS": omp}
    env.pop(ENV_VAR, None)
    run = subprocess.run(
        [sys.executable, "-c", _CHILD, str(folder)], capture_output=True, text=True, env=env, timeout=600, check=True
    )
    return run.stdout


def test_results_do_not_depend_on_the_environments_thread_count(tmp_path):
    for seed in range(20):
        image = render_scene(seed, size=(320, 240)).image
        cv2.imwrite(str(tmp_path / f"{seed:02d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    one, two = _child_rows(tmp_path, "1"), _child_rows(tmp_path, "2")
    assert len(json.loads(one)) == 20
    assert one == two
