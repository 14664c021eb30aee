"""Training under torchrun: 2 CPU processes (gloo) take the same steps as 1 process with the same global batch."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from mdgs.data.generate import GenerateConfig, generate


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    out = tmp_path_factory.mktemp("cubli")
    generate(GenerateConfig(scene="cubli-triple", out=str(out), preset="tiny"))
    return out


def _train(data, out, procs: int) -> subprocess.CompletedProcess:
    args = ["train", "--data", str(data), "--out", str(out), "--epochs", "2", "--max-steps", "3",
            "--batch-size", "8", "--device", "cpu", "--valid-max-pairs", "16"]
    launcher = [sys.executable, "-m", "mdgs.cli"] if procs == 1 else [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", str(procs),
        "-m", "mdgs.cli"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(launcher + args, capture_output=True, text=True, timeout=600, env=env)


def test_two_gloo_processes_match_one_process_with_the_same_global_batch(data, tmp_path):
    one, two = _train(data, tmp_path / "one", 1), _train(data, tmp_path / "two", 2)
    assert one.returncode == 0, one.stderr[-2000:]
    assert two.returncode == 0, two.stderr[-2000:]
    a = torch.load(tmp_path / "one" / "checkpoint.pt", weights_only=False)
    b = torch.load(tmp_path / "two" / "checkpoint.pt", weights_only=False)
    assert a["epoch"] == b["epoch"] == 1 and b["config"]["processes"] == 2
    # 6 Adam steps; the only difference is the float32 summation order of the gradient mean
    # (two half-batch means averaged by all-reduce vs one mean): 1e-5 of each tensor's scale
    for k in a["model"]:
        scale = float(a["model"][k].abs().max()) + 1e-12
        assert float((a["model"][k] - b["model"][k]).abs().max()) <= 1e-5 * scale, k
    # and the parameters did move (the comparison is not between two untrained models)
    assert a["history"][0]["train_mse"] != a["history"][1]["train_mse"]
    # one job, one voice: rank 0 prints the summary, rank 1 nothing
    assert two.stdout.count("epoch 2/2") == 1, two.stdout


def test_batch_not_divisible_by_processes_is_refused(data, tmp_path):
    env_args = ["--batch-size", "7"]
    res = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                          "-m", "mdgs.cli", "train", "--data", str(data), "--out", str(tmp_path / "r"),
                          "--epochs", "1", "--device", "cpu", *env_args],
                         capture_output=True, text=True, timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert res.returncode != 0 and "not divisible by the 2 processes" in res.stderr
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("model", ["gns", "lgns"])
def test_peers_train_under_torchrun(data, tmp_path, model):
    """Every model of the registry trains under DDP: GNS (5-frame history, per-step schedule) and
    LGNS (autodiff inside the loss, parameters unused on contact-free batches) as the hard cases."""
    res = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                          "-m", "mdgs.cli", "train", "--data", str(data), "--out", str(tmp_path / "r"), "--model", model,
                          "--epochs", "1", "--max-steps", "2", "--batch-size", "4", "--device", "cpu",
                          "--valid-max-pairs", "4"],
                         capture_output=True, text=True, timeout=900, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert res.returncode == 0, res.stderr[-2000:]
    state = torch.load(tmp_path / "r" / "checkpoint.pt", weights_only=False)
    assert state["model_name"] == model and state["config"]["processes"] == 2
