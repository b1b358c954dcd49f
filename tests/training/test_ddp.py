"""ZSNet training in two CPU processes (DDP, gloo) through ``ngp-train fit`` with the shipped config: it finishes,
writes its checkpoints, and the validation figures are averaged over both processes."""

import subprocess
import sys
from pathlib import Path

import pytest
import torch

pytestmark = pytest.mark.slow

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "zsnet.yaml"


def test_two_process_training_writes_a_checkpoint(tmp_path):
    runs, cache = tmp_path / "runs", tmp_path / "cache"
    overrides = {
        "trainer.devices": "2",
        "trainer.strategy": "ddp",
        "trainer.max_steps": "2",  # two steps: DDP checks in the second one that every gradient was reduced
        "trainer.default_root_dir": str(runs),
        "trainer.logger.init_args.save_dir": str(runs),
        "trainer.enable_progress_bar": "false",
        "model.init_args.net.init_args.width": "8",
        "data.cache_dir": str(cache),
        "data.train_size": "4",  # one batch of 2 per process and epoch
        "data.val_size": "2",
        "data.test_size": "2",
        "data.size": "[160, 120]",
        "data.batch_size": "2",
        "data.num_workers": "0",
    }
    command = [sys.executable, "-m", "ngp_kornia.training.command", "fit", "--config", str(CONFIG)]
    command += [f"--{key}={value}" for key, value in overrides.items()]
    # the working folder is tmp_path: Lightning re-runs this command for rank 1, and nothing lands in the repository
    run = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "MEMBER: 2/2" in run.stderr + run.stdout
    assert "sync_dist" not in run.stderr  # validation metrics are reduced over the processes
    checkpoints = runs / "lightning_logs" / "version_0" / "checkpoints"
    assert sorted(p.name for p in checkpoints.iterdir()) == ["best.ckpt", "last.ckpt"]
    checkpoint = torch.load(checkpoints / "last.ckpt", map_location="cpu", weights_only=False)
    assert checkpoint["global_step"] >= 1 and checkpoint["ngp_network"]["settings"]["width"] == 8
