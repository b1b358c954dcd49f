"""The thread policy: the pipeline runs on one thread by default, the caller's torch and OpenCV settings survive
every call (also a failing one), and the answer does not depend on the thread count of the caller's environment."""

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
from ngp_kornia.pipeline import NeuralGeometricParser, ParserConfig
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


@pytest.mark.parametrize("value, message", [("two", "is not an integer"), ("-1", "expected a thread count")])
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
        assert n == 1 and torch.get_num_threads() == 1 and cv2.getNumThreads() == 1
    assert torch.get_num_threads() == caller_threads and cv2.getNumThreads() == caller_threads
    with pytest.raises(RuntimeError, match="inside"), pipeline_threads(2):
        assert torch.get_num_threads() == 2
        raise RuntimeError("inside")
    assert torch.get_num_threads() == caller_threads and cv2.getNumThreads() == caller_threads


def test_zero_leaves_the_caller_alone(caller_threads):
    with pipeline_threads(0) as n:
        assert n == caller_threads and torch.get_num_threads() == caller_threads
    assert torch.get_num_threads() == caller_threads


def test_nested_and_overlapping_scopes_restore_once(caller_threads):
    with pipeline_threads(1):
        with pipeline_threads(1):
            pass
        assert torch.get_num_threads() == 1  # the inner exit does not restore under the outer scope
    assert torch.get_num_threads() == caller_threads
    # two Python threads whose scopes overlap: A enters, B enters, A leaves, B leaves
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    inside_b_after_a = []

    def first():
        with pipeline_threads(1):
            a_in.set()
            b_in.wait(10)
        a_out.set()

    def second():
        a_in.wait(10)
        with pipeline_threads(1):
            b_in.set()
            a_out.wait(10)
            inside_b_after_a.append(torch.get_num_threads())  # A has left, B is still inside

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(20)
    assert inside_b_after_a == [1]
    assert torch.get_num_threads() == caller_threads and cv2.getNumThreads() == caller_threads


def test_calibrate_keeps_the_callers_thread_count(caller_threads, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    seen = []
    original = NeuralGeometricParser.score_frames

    def spy(self, *args, **kwargs):
        seen.append(torch.get_num_threads())
        return original(self, *args, **kwargs)

    monkeypatch.setattr(NeuralGeometricParser, "score_frames", spy)
    image = render_scene(1, size=(160, 120)).image
    calibrate(image)
    assert seen == [1] and torch.get_num_threads() == caller_threads
    calibrate(image, config=ParserConfig(num_threads=2))
    assert seen[-1] == 2 and torch.get_num_threads() == caller_threads
    calibrate(image, config=ParserConfig(num_threads=0))
    assert seen[-1] == caller_threads and torch.get_num_threads() == caller_threads


def test_calibrate_restores_after_an_exception_inside(caller_threads, monkeypatch):
    def fail(self, *args, **kwargs):
        assert torch.get_num_threads() == 1
        raise RuntimeError("failed inside the parser")

    monkeypatch.setattr(NeuralGeometricParser, "score_frames", fail)
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


def test_work_beside_runs_on_a_helper_in_the_callers_modes():
    from ngp_kornia.threads import helper_threads, run_beside, usable_cores

    if usable_cores() < 2:
        pytest.skip("needs two cores: with one, the work runs in the caller's thread")

    started = threading.Event()

    def where():
        started.set()
        return threading.current_thread() is threading.main_thread(), torch.get_num_threads(), (
            torch.is_inference_mode_enabled()
        )

    with pipeline_threads(1), torch.inference_mode():
        work = run_beside(where)
        started.wait(timeout=60)  # the caller goes on with other work meanwhile; here it waits for the helper
        in_main, threads, inference = work.result()
    assert not in_main and threads == 1 and inference  # the caller's thread count and inference mode
    with helper_threads(1), torch.no_grad():
        assert run_beside(where).result()[0]  # no spare thread allowed: the caller computes it
    assert run_beside(where).result()[0]  # with autograd on, never beside (a gradient does not cross threads)


def test_work_beside_raises_in_the_caller():
    from ngp_kornia.threads import run_beside

    def fail():
        raise ValueError("inside the helper")

    with torch.no_grad(), pytest.raises(ValueError, match="inside the helper"):
        run_beside(fail).result()


def test_answers_do_not_depend_on_fsnets_image_side_running_beside():
    """FSNet's frame-free part runs on a helper thread while the frames are scored; on one thread (a process's
    share of one core in ngp predict) the answer is the same to the last bit."""
    from ngp_kornia.threads import helper_threads

    image = render_scene(4, size=(320, 240)).image
    beside = calibrate(image).to_dict()
    with helper_threads(1):
        alone = calibrate(image).to_dict()
    for name, value in beside.items():
        assert torch.equal(value, alone[name]) if isinstance(value, torch.Tensor) else value == alone[name], name


def _two_cores():
    from ngp_kornia.threads import usable_cores

    if usable_cores() < 2:
        pytest.skip("needs two cores: with one, no work is handed to a helper")


def _held_helper_work():
    """Work a helper has started and goes on with for a moment after the caller asks for its result."""
    from ngp_kornia.threads import Beside

    started, release = threading.Event(), threading.Event()

    def work():
        started.set()
        return release.wait(timeout=60)

    beside = Beside.start(work)
    assert started.wait(timeout=60)
    threading.Timer(0.2, release.set).start()
    return beside


def test_a_thread_does_its_waiting_job_instead_of_waiting_idle():
    """While a helper is still at its work, the caller computes the job of ``while_waiting`` itself."""
    from ngp_kornia.threads import while_waiting

    _two_cores()
    with torch.no_grad(), while_waiting(lambda: threading.current_thread() is threading.main_thread()) as job:
        work = _held_helper_work()
        assert work.result()
        assert job.ran  # done while the helper was still at its work...
    assert job.result()  # ...by the caller


def test_a_helper_done_first_takes_up_the_waiting_job():
    from ngp_kornia.threads import Beside, while_waiting

    _two_cores()
    gate, done = threading.Event(), threading.Event()

    def job():
        done.set()
        return threading.current_thread() is threading.main_thread()

    with torch.no_grad(), while_waiting(job) as waiting:
        work = Beside.start(gate.wait, 60)
        gate.set()
        assert done.wait(timeout=60)  # this thread is still busy: the helper, done with its work, takes the job up
        assert work.result()
    assert waiting.result() is False


def test_a_waiting_job_left_alone_is_computed_on_demand_and_keeps_its_error():
    from ngp_kornia.threads import helper_threads, run_beside, while_waiting

    def fail():
        raise ValueError("inside the job")

    with torch.no_grad(), helper_threads(1), while_waiting(fail) as job:
        assert run_beside(lambda: 2).result() == 2
        assert not job.ran  # one thread: nothing was handed to a helper, so nothing was waited for
    with pytest.raises(ValueError, match="inside the job"):
        job.result()


def test_a_failing_waiting_job_does_not_break_the_work_waited_for():
    from ngp_kornia.threads import while_waiting

    _two_cores()

    def fail():
        raise ValueError("inside the job")

    with torch.no_grad(), while_waiting(fail) as job:
        work = _held_helper_work()
        assert work.result()
        assert job.ran
    with pytest.raises(ValueError, match="inside the job"):
        job.result()


def test_calibrate_resizes_fsnets_image_while_waiting_for_line_detection(monkeypatch):
    """With two threads, FSNet's resized image is made in line detection's gap and handed to the parser: the
    answer is the one the parser gives when it resizes the image itself."""
    import ngp_kornia.api as api
    from ngp_kornia.threads import helper_threads

    _two_cores()
    image = render_scene(6, size=(320, 240)).image
    handed = []
    parser_call = NeuralGeometricParser.forward

    def spy(self, *args, fsnet_images=None, **kwargs):
        handed.append(fsnet_images is not None)
        return parser_call(self, *args, fsnet_images=fsnet_images, **kwargs)

    monkeypatch.setattr(NeuralGeometricParser, "forward", spy)
    made = [calibrate(image).to_dict() for _ in range(5)]
    with helper_threads(1):
        alone = calibrate(image).to_dict()
    assert any(handed[:5]) and not handed[5]
    for result in made:
        for name, value in result.items():
            assert torch.equal(value, alone[name]) if isinstance(value, torch.Tensor) else value == alone[name], name
    assert api._fsnet_size("none") is None
    assert api._fsnet_size("default") == api.load_parser("default").fsnet.input_size
