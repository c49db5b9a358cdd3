"""A motion library through the whole workflow (issue 35): the tiny pants wear two real clips of the shared CMU
library, one of a subject held out whole, beside a broken file, a skeleton the mannequin cannot be mapped to and a
clip that teleports the body; the run completes, trains on the good clips, holds the subject out, and lists each
bad one with its reason in the dataset and the report. Skipped where the shared library is absent."""
from __future__ import annotations

import gzip
import shutil

import h5py
import numpy as np
import pytest
import yaml

from pipeline.artifacts.dataset import DROPPED_NAMES, DROPPED_REASONS, SEQUENCE_NAMES, WINDOW_FIELDS
from workflow_runs import REPO, build, planned_jobs, snakemake, tail, tiny_pants

SHARED = REPO.parent / "shared" / "mocap" / "cmu"
GOOD = {"003/03_01.bvh.gz": "3", "007/07_01.bvh.gz": "7"}      # a walk on uneven terrain; a walk (held out)
TELEPORT_FRAME = 200                                         # of 03_01 (120 fps): 1.6 s in, inside its window


def teleported(text: str) -> str:
    """A BVH text whose root jumps 3 m sideways (its first channel, X position, in cm) from TELEPORT_FRAME on."""
    head, motion = text.split("Frame Time:", 1)
    lines = motion.splitlines()
    frames = lines[1:]           # lines[0] is the frame time
    for k in range(TELEPORT_FRAME, len(frames)):
        values = frames[k].split()
        values[0] = repr(float(values[0]) + 300.0)
        frames[k] = " ".join(values)
    return head + "Frame Time:" + "\n".join([lines[0], *frames]) + "\n"


@pytest.fixture(scope="module")
def library_run(tmp_path_factory):
    if not SHARED.is_dir():
        pytest.skip(f"the shared CMU library is not at {SHARED}")
    workdir = tmp_path_factory.mktemp("library")
    library = workdir / "mocap"
    for file in GOOD:
        (library / file).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(SHARED / file, library / file)
    (library / "003/03_01_teleport.bvh").write_text(teleported(gzip.decompress((SHARED / "003/03_01.bvh.gz")
                                                                              .read_bytes()).decode()))
    (library / "003/03_02_broken.bvh.gz").write_bytes(b"\x1f\x8b this is not gzip")
    (library / "009").mkdir()
    (library / "009/robot.bvh").write_text(
        "HIERARCHY\nROOT base\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
        "Yrotation\n JOINT arm\n {\n  OFFSET 0 50 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  End Site\n  {\n"
        "   OFFSET 0 50 0\n  }\n }\n}\nMOTION\nFrames: 300\nFrame Time: 0.0166667\n"
        + "0 90 0 0 0 0 0 0 0\n" * 300)
    config = tiny_pants(workdir, sequences=0, shard=2)
    overlay = yaml.safe_load(config.read_text())
    pants = overlay["profiles"]["cpu"]["scenes"]["pants"]
    pants["drivers"]["mannequin"]["library"] = {"dir": str(library), "manifest": None, "fps_column": None,
                                               "frame_rates": {}, "window": 4.0, "hold_frames": 3}
    pants["library_windows"] = {"include": ["*"], "exclude": [], "max_clips": 0, "held_out_subjects": ["007"]}
    config.write_text(yaml.safe_dump(overlay))
    run = build(workdir, "results/pants/", "--configfile", str(config))
    return workdir, run


def test_the_run_completes_trains_on_the_good_clips_and_lists_each_bad_one(library_run):
    workdir, run = library_run
    assert run.returncode == 0, tail(run)
    with h5py.File(workdir / "results/pants/dataset.h5") as f:
        names = [n.decode() for n in f[SEQUENCE_NAMES][()]]
        subjects = [s.decode() for s in f[WINDOW_FIELDS["subject"]][()]]
        dropped = dict(zip((n.decode() for n in f[DROPPED_NAMES][()]),
                           (r.decode() for r in f[DROPPED_REASONS][()])))
    # The good windows (sequences 0: no programs), the held-out walk of the profile, the held-out subject's window.
    assert names == ["train_003-03-01_w00", "held_out_000", "held_out_007-07-01_w00"]
    assert subjects == ["3", "", "7"]
    # The robot's 4.85 s make two windows, each dropped; the broken file's unread header one.
    assert set(dropped) == {"train_003-03-01-teleport_w00", "train_003-03-02-broken_w00", "train_009-robot_w00",
                            "train_009-robot_w01"}
    teleport = dropped["train_003-03-01-teleport_w00"]
    assert "blew up" in teleport or "tangled" in teleport, teleport
    assert "03_02_broken.bvh.gz" in dropped["train_003-03-02-broken_w00"]
    assert "robot.bvh" in dropped["train_009-robot_w00"] and "pelvis" in dropped["train_009-robot_w00"]
    report = (workdir / "results/pants/report.md").read_text()
    assert all(name in report for name in dropped)
    held = workdir / "results/pants/sequences/held_out_007-07-01_w00"
    with h5py.File(held / "scene.h5") as f:
        frames = int(f.attrs["frames"])
    with h5py.File(held / "sim_high.h5") as f, h5py.File(workdir / "results/pants/settle/sim_high.h5") as settle:
        # the lead-in (5 blend, 3 hold) and the clip's 2.6 s after its T-pose, at 60 frames a second, from the cloth
        # settled once (3 frames at rest) for every window
        assert f["positions"].shape[0] == frames > 5 + 3 + 150 and np.isfinite(f["positions"][()]).all()
        assert settle["positions"].shape[0] == 3 + 1
        np.testing.assert_array_equal(f["positions"][0], settle["positions"][-1])


def test_the_plan_settles_once_then_steps_every_low_res_shard_before_the_high_res_ones(tmp_path):
    """The settle sequence's jobs, the windows' jobs given its runs (`--settled`), and the priorities that put the
    settle runs first and every low-res shard before any high-res one on a GPU taken one job at a time."""
    if not SHARED.is_dir():
        pytest.skip(f"the shared CMU library is not at {SHARED}")
    config = tiny_pants(tmp_path, sequences=1, shard=2)
    overlay = yaml.safe_load(config.read_text())
    pants = overlay["profiles"]["cpu"]["scenes"]["pants"]
    pants["drivers"]["mannequin"]["library"] = {"dir": str(SHARED), "manifest": None, "fps_column": None,
                                               "frame_rates": {}, "window": 4.0, "hold_frames": 3}
    pants["library_windows"] = {"include": ["003/03_01.bvh.gz"], "exclude": [], "max_clips": 0,
                                "held_out_subjects": []}
    config.write_text(yaml.safe_dump(overlay))
    run = snakemake(tmp_path, "-n", "-p", "results/pants/", "--configfile", str(config), "--config", "device=cuda:0")
    assert run.returncode == 0, tail(run)
    jobs = planned_jobs(run)
    assert jobs["settle_scene"]["shell"].split(" 2>&1")[0].endswith("results/pants/settle/scene.h5 --sequence settle")
    # Shard 0 holds the program train_000 and the window, whose runs start from the settle runs of their level.
    for level in ("low", "high"):
        shard = jobs[f"simulate_{level}_batch_pants_000"]
        assert f" --settled results/pants/settle/sim_{level}.h5 " in shard["shell"]
        assert f"results/pants/settle/sim_{level}.h5" in shard["input"]
    assert "--settled" not in jobs["simulate_low_batch_pants_001"]["shell"]     # the held-out walk: no window
    priority = {name: int(job.get("priority", 0)) for name, job in jobs.items()}
    assert priority["simulate_settle_low"] == priority["simulate_settle_high"] > priority["sequence"] \
        == priority["simulate_low_batch_pants_000"] > priority["simulate_high_batch_pants_000"] == 0
