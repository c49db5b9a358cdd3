"""The train stage under `torchrun --nproc_per_node=2` on the CPU (gloo): two ranks at a batch of B train the model
one process trains at 2 x B, rank 0 alone writes the checkpoint and the outputs, and a run killed mid-training
resumes to the weights of an uninterrupted one; on CUDA each rank's GPU is its own."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from pipeline import dataset, operators, train
from pipeline.core.gpu_slots import GPUS_VARIABLE, LOCKS_VARIABLE
from pipeline.core.h5 import config_of
from stage_inputs import stage, write_waving_sheet

REPO = Path(__file__).resolve().parents[2]
ARCH = ["--arch", "D8 D16 D D16", "--conv", "RC7"]
FLAGS = ["--threads", "1", "--quiet"]
# 2 ranks against one process: the same frames and gradients, the sums in another order (gloo's reduction,
# per-rank means). Adam divides each gradient by its own running RMS, so rounding-level differences of small
# gradients become differences of the steps, and they compound: measured on this problem, after 3 epochs
# (9 steps) the weights differ by 4.6e-6 at most (of weights up to 0.2) and the losses by 1e-7 relative;
# after 24 epochs by 4e-3 and 2 %. The equivalence is checked after 3 epochs, against these bounds.
EQUAL_EPOCHS = ["--epochs", "3"]
WEIGHT_ATOL, LOSS_RTOL = 2e-5, 1e-6
RESUME_EPOCHS = ["--epochs", "24"]


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("torchrun")
    write_waving_sheet(folder)        # 12 frames: 11 train, 1 test
    stage(operators.main, folder / "subdiv.h5", folder / "operators.h5", "--conv", "RC7", "--levels", "4", "--quiet")
    stage(dataset.main, folder / "subdiv.h5", folder / "dataset.h5", folder, "--quiet")
    return folder


def train_command(work: Path, out: Path, *flags: str) -> list[str]:
    return ["-m", "pipeline.train", str(work / "dataset.h5"), str(work / "operators.h5"), str(out),
            str(out.with_suffix(".h5")), *ARCH, *FLAGS, *flags]


def torchrun(work: Path, out: Path, *flags: str) -> None:
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
               *train_command(work, out, *flags)]
    run = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]


def ranks_by_hand(work: Path, out: Path, *flags: str) -> list[subprocess.Popen]:
    """The two ranks as torchrun starts them (its environment variables), but as this test's own processes: a
    kill reaches both at once, as when a job's allocation ends (torchrun's workers outlive a killed launcher)."""
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    return [subprocess.Popen([sys.executable, *train_command(work, out, *flags)], cwd=REPO,
                             env={**os.environ, "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port),
                                  "WORLD_SIZE": "2", "RANK": str(rank), "LOCAL_RANK": str(rank)},
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for rank in (0, 1)]


def weights(path: Path) -> dict[str, torch.Tensor]:
    return torch.load(path, weights_only=True)["state_dict"]


# Batch 2: each epoch's 11 frames are two full steps of 4 and a last one of 3 (2 + 1). Batch 5: a full step of
# 10, then 1 frame, so rank 1 runs a frame of weight 0; and the ranks stream their frames from disk (each reads
# only its own). Rank 1 has no test frame to score either way.
@pytest.mark.parametrize("batch, streamed", [(2, False), (5, True)])
def test_two_ranks_train_the_model_of_one_process_at_twice_the_batch(work, tmp_path, batch, streamed):
    ranked, single = tmp_path / "ranks.pt", tmp_path / "single.pt"
    torchrun(work, ranked, *EQUAL_EPOCHS, "--batch-size", str(batch), *(["--device-cache-gb", "0"] * streamed))
    stage(train.main, work / "dataset.h5", work / "operators.h5", single, single.with_suffix(".h5"), *ARCH, *FLAGS,
          *EQUAL_EPOCHS, "--batch-size", str(2 * batch))
    one, two = weights(single), weights(ranked)
    assert one.keys() == two.keys()
    assert any(not torch.equal(one[name], two[name]) for name in one)    # two runs, not one file read twice
    for name in one:
        torch.testing.assert_close(two[name], one[name], rtol=0, atol=WEIGHT_ATOL)
    with h5py.File(single.with_suffix(".h5")) as a, h5py.File(ranked.with_suffix(".h5")) as b:
        # the history is every rank's frames': the same losses as the one process's
        for name in ("epoch/train_total", "epoch/test_total", "batch/total"):
            np.testing.assert_allclose(b[name][()], a[name][()], rtol=LOSS_RTOL)
        assert len(b["batch/total"][()]) == 3 * -(-11 // (2 * batch))
        assert config_of(b)["batch_size"] == batch
    model = torch.load(ranked, weights_only=True)
    assert model["training"]["ranks"] == 2 and model["training"]["batch_size"] == batch
    assert model["training"]["streamed"] == streamed
    assert not list(ranked.parent.glob("*.ckpt")) and not list(ranked.parent.glob(".*tmp*"))


def test_a_killed_two_rank_run_resumes_to_the_uninterrupted_weights(work, tmp_path):
    uninterrupted_run, out = tmp_path / "uninterrupted.pt", tmp_path / "killed.pt"
    torchrun(work, uninterrupted_run, *RESUME_EPOCHS, "--batch-size", "2")
    checkpoint = Path(f"{out}.ckpt")
    killed = ranks_by_hand(work, out, *RESUME_EPOCHS, "--batch-size", "2")
    deadline = time.monotonic() + 120
    while not checkpoint.exists() and killed[0].poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    for rank in killed:
        rank.kill()
        rank.wait()
    assert checkpoint.exists() and not out.exists(), "the run must be killed mid-training"
    torchrun(work, out, *RESUME_EPOCHS, "--batch-size", "2")
    with h5py.File(out.with_suffix(".h5")) as resumed, \
            h5py.File(uninterrupted_run.with_suffix(".h5")) as uninterrupted:
        assert resumed.attrs["resumed_from_epoch"] > 0
        np.testing.assert_allclose(resumed["epoch/train_total"][()], uninterrupted["epoch/train_total"][()],
                                   rtol=1e-6)
    resumed, uninterrupted = weights(out), weights(uninterrupted_run)
    for name in uninterrupted:
        torch.testing.assert_close(resumed[name], uninterrupted[name], rtol=1e-6, atol=1e-7)


# A rank choosing its device, then living until stdin closes (holding any GPU slot it took).
RANK_DEVICE = ("import os, sys; from model.data_parallel import Ranks; from pipeline.train import rank_device; "
               "rank = int(sys.argv[1]); print(rank_device(Ranks(rank, 2, rank), 'cuda:0'), "
               "os.environ.get('CUDA_VISIBLE_DEVICES'), flush=True); sys.stdin.read()")


@pytest.mark.parametrize("pool", [None, "2"])
def test_each_rank_on_cuda_takes_a_gpu_of_its_own(tmp_path, pool):
    """Under torchrun or Slurm (no pool) rank r is cuda:LOCAL_RANK of the launcher's GPUs; in the workflow's
    shared pool (`gpus: N`, pipeline.core.gpu_slots) each rank locks a free GPU and sees it alone as cuda:0."""
    env = {key: value for key, value in os.environ.items() if key not in ("CUDA_VISIBLE_DEVICES", GPUS_VARIABLE)}
    env[LOCKS_VARIABLE] = str(tmp_path / "locks")
    if pool is not None:
        env[GPUS_VARIABLE] = pool
    ranks = [subprocess.Popen([sys.executable, "-c", RANK_DEVICE, str(rank)], cwd=REPO, env=env, text=True,
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE) for rank in (0, 1)]
    seen = [rank.stdout.readline().split() for rank in ranks]
    for rank in ranks:
        rank.communicate("")
    if pool is None:
        assert seen == [["cuda:0", "None"], ["cuda:1", "None"]]
    else:
        assert [device for device, _ in seen] == ["cuda:0", "cuda:0"] and sorted(g for _, g in seen) == ["0", "1"]


def test_a_bad_launcher_environment_is_one_error(tmp_path):
    env = {**os.environ, "WORLD_SIZE": "2", "RANK": "2", "LOCAL_RANK": "0"}
    run = subprocess.run([sys.executable, *train_command(tmp_path, tmp_path / "model.pt")], cwd=REPO, env=env,
                         capture_output=True, text=True)
    assert run.returncode == 2 and run.stderr.strip().splitlines() == [
        "error: torchrun's environment: RANK 2 of WORLD_SIZE 2: a rank must lie in 0 .. WORLD_SIZE - 1"]
    assert not list(tmp_path.iterdir())
