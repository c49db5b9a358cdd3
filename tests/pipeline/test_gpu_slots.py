"""Several GPUs shared by jobs: each process takes a GPU no other live process holds, waits when all are held, and
gets its GPU back the moment its holder ends (crash or kill included). Checked with real processes and flock."""
import os
import subprocess
import sys

import pytest

from pipeline.core.errors import PipelineError
from pipeline.core.gpu_slots import (GPUS_VARIABLE, JOBS_PER_GPU_VARIABLE, LOCKS_VARIABLE, RUN_VARIABLE,
                                     _jobs_per_gpu, _slot_ids)

# A job: take a GPU, say which (and what its children would be told), then live until stdin closes.
# The fourth word: how many jobs share its GPU, which the times it measures name (pipeline.core.torch_setup).
JOB = ("import os, sys; from pipeline.core.gpu_slots import claim_gpu, jobs_sharing_the_gpu; "
       "gpu = claim_gpu(poll_seconds=0.05); print(gpu, os.environ['CUDA_VISIBLE_DEVICES'], "
       "os.environ['LEARNED_CLOTH_GPUS'], jobs_sharing_the_gpu(), flush=True); "
       "sys.stdin.read()")


WHOLE_JOB = JOB.replace("claim_gpu(poll_seconds=0.05)", "claim_gpu(poll_seconds=0.05, whole=True)")


def start_job(tmp_path, count, visible=None, per_gpu=None, rank_of=None, whole=False):
    """A job process; `rank_of`: a torchrun run id, making it one of that job's two ranks; `whole`: it takes its
    GPU whole."""
    env = {**os.environ, GPUS_VARIABLE: str(count), LOCKS_VARIABLE: str(tmp_path / "locks")}
    env.pop(RUN_VARIABLE, None)
    env.pop("WORLD_SIZE", None)
    if rank_of is not None:
        env.update({RUN_VARIABLE: rank_of, "WORLD_SIZE": "2"})
    env.pop(JOBS_PER_GPU_VARIABLE, None)
    if per_gpu is not None:
        env[JOBS_PER_GPU_VARIABLE] = str(per_gpu)
    env.pop("CUDA_VISIBLE_DEVICES", None)
    if visible is not None:
        env["CUDA_VISIBLE_DEVICES"] = visible
    return subprocess.Popen([sys.executable, "-c", WHOLE_JOB if whole else JOB], env=env, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_jobs_take_distinct_gpus_wait_and_get_a_released_one(tmp_path):
    first, second = start_job(tmp_path, 2), start_job(tmp_path, 2)
    first_gpu, second_gpu = first.stdout.readline().split()[0], second.stdout.readline().split()[0]
    assert {first_gpu, second_gpu} == {"0", "1"}
    third = start_job(tmp_path, 2)           # both held: it waits
    assert "waiting" in third.stderr.readline()
    assert third.poll() is None
    first.kill()                            # a killed holder's lock goes with it
    first.wait()
    # The freed GPU, seen alone; its own children are not told to share again.
    assert third.stdout.readline().split() == [first_gpu, first_gpu, "1", "1"]
    for job in (second, third):
        job.communicate("")


def test_slots_are_the_first_of_a_schedulers_gpus(tmp_path):
    job = start_job(tmp_path, 2, visible="3,5,7")
    assert job.stdout.readline().split()[:2] == ["3", "3"]
    job.communicate("")


@pytest.mark.parametrize("count, visible, ids", [(None, None, None), ("1", "0,1", None), ("2", None, ["0", "1"]),
                                                 ("2", "4,6,8", ["4", "6"])])
def test_slot_ids(count, visible, ids):
    assert _slot_ids(count, visible) == ids


@pytest.mark.parametrize("count, visible", [("two", None), ("0", None), ("-1", None), ("3", "0,1")])
def test_bad_counts_are_one_error(count, visible):
    with pytest.raises(PipelineError, match=GPUS_VARIABLE):
        _slot_ids(count, visible)


def test_with_two_jobs_a_gpu_they_spread_over_the_gpus_before_they_share_one(tmp_path):
    jobs, gpus = [], []
    for _ in range(4):                      # one at a time, so the order of the slots they take is the test's
        jobs.append(start_job(tmp_path, 2, per_gpu=2))
        gpu, _, _, sharing = jobs[-1].stdout.readline().split()
        gpus.append(gpu)
        assert sharing == "2"
    assert gpus == ["0", "1", "0", "1"]
    fifth = start_job(tmp_path, 2, per_gpu=2)
    assert "waiting" in fifth.stderr.readline() and fifth.poll() is None
    jobs[2].kill()                          # the third took GPU 0's second slot: the fifth gets it
    jobs[2].wait()
    assert fifth.stdout.readline().split()[0] == "0"
    for job in (*jobs[:2], jobs[3], fifth):
        job.communicate("")


def test_the_ranks_of_one_job_never_share_a_gpu(tmp_path):
    # Two GPUs of two slots, all four held; then GPU 0's two slots freed: a job's first rank takes one, and its
    # second passes the other by (NCCL refuses two ranks on one GPU) until GPU 1 has a free slot.
    jobs, gpus = [], []
    for _ in range(4):                      # one after another: each takes the first free slot
        jobs.append(start_job(tmp_path, 2, per_gpu=2))
        gpus.append(jobs[-1].stdout.readline().split()[0])
    assert gpus == ["0", "1", "0", "1"]
    for job in (jobs[0], jobs[2]):
        job.kill()
        job.wait()
    first = start_job(tmp_path, 2, per_gpu=2, rank_of="run-a")
    assert first.stdout.readline().split()[0] == "0"
    second = start_job(tmp_path, 2, per_gpu=2, rank_of="run-a")
    assert "waiting" in second.stderr.readline() and second.poll() is None
    other = start_job(tmp_path, 2, per_gpu=2, rank_of="run-b")    # another job's rank takes GPU 0's free slot
    assert other.stdout.readline().split()[0] == "0"
    jobs[1].kill()
    jobs[1].wait()
    assert second.stdout.readline().split()[0] == "1"
    for job in (jobs[3], first, second, other):
        job.communicate("")


def test_a_whole_gpu_is_one_with_every_slot_free_and_its_job_shares_it_with_none(tmp_path):
    # Two GPUs of two slots. A job takes GPU 0's first slot; a whole claim passes GPU 0 by and takes both of GPU
    # 1's (sharing it with none); the next job gets GPU 0's second slot. A second whole claim then waits, and
    # holds no slot meanwhile: with GPU 0's first slot freed, a plain job still gets it.
    single = start_job(tmp_path, 2, per_gpu=2)
    assert single.stdout.readline().split()[0] == "0"
    whole = start_job(tmp_path, 2, per_gpu=2, whole=True)
    assert whole.stdout.readline().split() == ["1", "1", "1", "1"]
    second = start_job(tmp_path, 2, per_gpu=2)
    assert second.stdout.readline().split()[0] == "0"
    waiting = start_job(tmp_path, 2, per_gpu=2, whole=True)
    assert "all its slots free" in waiting.stderr.readline() and waiting.poll() is None
    single.kill()
    single.wait()
    third = start_job(tmp_path, 2, per_gpu=2)
    assert third.stdout.readline().split()[0] == "0" and waiting.poll() is None
    for job in (second, third):
        job.kill()
        job.wait()
    assert waiting.stdout.readline().split()[:2] == ["0", "0"]
    for job in (whole, waiting):
        job.communicate("")


def test_the_ranks_of_one_job_take_distinct_gpus_whole(tmp_path):
    first = start_job(tmp_path, 2, per_gpu=2, rank_of="run-a", whole=True)
    second = start_job(tmp_path, 2, per_gpu=2, rank_of="run-a", whole=True)
    assert {first.stdout.readline().split()[0], second.stdout.readline().split()[0]} == {"0", "1"}
    for job in (first, second):
        job.communicate("")


@pytest.mark.parametrize("text, count", [(None, 1), ("", 1), ("3", 3)])
def test_jobs_per_gpu(text, count):
    assert _jobs_per_gpu(text) == count


@pytest.mark.parametrize("text", ["0", "two", "-2", "65"])
def test_bad_jobs_per_gpu_are_one_error(text):
    with pytest.raises(PipelineError, match=JOBS_PER_GPU_VARIABLE):
        _jobs_per_gpu(text)
