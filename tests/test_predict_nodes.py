"""ngp predict over several machines, here two "nodes" of one process each on this machine's loopback, started as a
scheduler starts them: two commands with --num-nodes 2 and the environment Lightning reads (NODE_RANK, MASTER_ADDR,
MASTER_PORT, WORLD_SIZE, LOCAL_RANK; or SLURM's). Every image gets its row exactly once, the rows of a single
process; a resumed run whose last image is left to one node (the other has none) too; and two processes that
torchrun starts."""

import json
import os
import socket
import subprocess
import sys

import cv2
import pytest

from ngp_kornia.predict import predict_folder
from ngp_kornia.training.synth.render import render_scene

pytestmark = pytest.mark.slow


def _rows(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def _close(got, expected) -> bool:
    """The same rows in the same order, numbers equal to the rounding of their sixth significant digit: processes
    laid out otherwise may sum in another order (another thread count, say), and a last digit may round otherwise."""
    if isinstance(expected, dict):
        return isinstance(got, dict) and got.keys() == expected.keys() and all(
            _close(got[k], expected[k]) for k in expected)
    if isinstance(expected, list):
        return isinstance(got, list) and len(got) == len(expected) and all(map(_close, got, expected))
    if isinstance(expected, float) and isinstance(got, (int, float)) and not isinstance(got, bool):
        return got == pytest.approx(expected, rel=2e-5, abs=1e-6)
    return got == expected


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Nine small scenes and a broken file, and the rows one process writes for them."""
    folder = tmp_path_factory.mktemp("photos")
    for seed in range(9):
        image = render_scene(seed, size=(160, 120)).image
        cv2.imwrite(str(folder / f"scene{seed:02d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    (folder / "zz_broken.jpg").write_bytes(b"\xff\xd8 not a jpeg")
    out = tmp_path_factory.mktemp("single") / "rows.jsonl"
    predict_folder(folder, out)
    return folder, _rows(out)


def _scheduler_env(scheduler: str, rank: int, port: int) -> dict:
    """What a scheduler sets for node ``rank`` of two, one process each: as Lightning documents for a cluster of
    its own (NODE_RANK, MASTER_ADDR, MASTER_PORT), or as SLURM's srun sets it."""
    if scheduler == "slurm":
        return {"SLURM_NTASKS": "2", "SLURM_NTASKS_PER_NODE": "1", "SLURM_NNODES": "2", "SLURM_PROCID": str(rank),
                "SLURM_LOCALID": "0", "SLURM_NODEID": str(rank), "SLURM_JOB_NAME": "ngp", "SLURM_JOB_ID": "4242",
                "SLURM_NODELIST": "127.0.0.1", "MASTER_PORT": str(port)}
    return {"MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port), "NODE_RANK": str(rank), "WORLD_SIZE": "2",
            "LOCAL_RANK": "0"}


def _two_nodes(folder, out, *options, scheduler: str = "lightning") -> list[subprocess.CompletedProcess]:
    """``ngp predict`` as node 0 and node 1 of a two-node run on the loopback, run to their end."""
    port = _free_port()
    clean = {k: v for k, v in os.environ.items() if not k.startswith("SLURM_")}
    nodes = []
    for rank in (0, 1):
        command = [sys.executable, "-m", "ngp_kornia.cli", "predict", str(folder), "--out", str(out),
                   "--num-nodes", "2", *options]
        env = {**clean, **_scheduler_env(scheduler, rank, port)}
        nodes.append(subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    done = []
    for node in nodes:
        stdout, stderr = node.communicate(timeout=240)
        done.append(subprocess.CompletedProcess(node.args, node.returncode, stdout, stderr))
    return done


@pytest.mark.parametrize("scheduler", ["lightning", "slurm"])
def test_two_nodes_write_every_row_exactly_once(scenes, tmp_path, scheduler):
    folder, expected = scenes
    out = tmp_path / "rows.jsonl"
    first, second = _two_nodes(folder, out, scheduler=scheduler)
    assert first.returncode == 1, first.stderr[-3000:]  # 1: the broken file's row
    assert first.stdout.strip() == f"10 rows written to {out}" and "Traceback" not in first.stderr
    assert second.returncode == 0, second.stderr[-3000:]
    assert second.stdout.strip() == f"process 1: 5 rows calibrated; process 0 writes every row to {out}"
    assert _close(_rows(out), expected)  # in folder order, each image once, the rows of one process
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rows.jsonl"]  # no run folder left


def test_two_processes_started_by_torchrun(scenes, tmp_path):
    folder, expected = scenes
    out = tmp_path / "rows.jsonl"
    command = [sys.executable, "-m", "torch.distributed.run", "--nproc-per-node", "2", "--master-addr", "127.0.0.1",
               "--master-port", str(_free_port()), "-m", "ngp_kornia.cli", "predict", str(folder), "--out", str(out),
               "--devices", "2"]
    run = subprocess.run(command, capture_output=True, text=True, timeout=240)
    assert "10 rows written" in run.stdout and "process 1: 5 rows calibrated" in run.stdout, run.stderr[-3000:]
    assert _close(_rows(out), expected) and sorted(p.name for p in tmp_path.iterdir()) == ["rows.jsonl"]


def test_two_nodes_resume_a_run_with_one_image_left(scenes, tmp_path):
    from ngp_kornia.data.folder import ImageFolder
    from ngp_kornia.data.image_list import ImageList
    from ngp_kornia.predict import plan_run
    from ngp_kornia.rowfiles import RunFolder

    folder, expected = scenes
    out = tmp_path / "rows.jsonl"
    run = RunFolder(out)  # what a killed run left: every row but the sixth (scene05.png)
    run.start({**plan_run(ImageList.from_folder(ImageFolder(folder)), out).state, "attempt": "0badc0de"}, False)
    lines = [f"{i}\t{json.dumps(row)}\n" for i, row in enumerate(expected) if i != 5]
    run.rows_file("0badc0de", 0).write_text("".join(lines))
    first, second = _two_nodes(folder, out, "--resume")
    assert first.returncode == 1 and "10 rows written" in first.stdout, first.stderr[-3000:]
    assert first.stderr.splitlines()[0] == f"ngp: resuming {out}: 9 of 10 images have their row; calibrating 1"
    assert second.returncode == 0 and "process 1: 0 rows calibrated" in second.stdout, second.stderr[-3000:]
    assert second.stderr == ""  # only the first process says what it resumes
    assert _close(_rows(out), expected) and sorted(p.name for p in tmp_path.iterdir()) == ["rows.jsonl"]
