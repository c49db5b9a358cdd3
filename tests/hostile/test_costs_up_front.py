"""Costs nobody stated (issue 41 items 9-11, 15): a config's sequences, a clip's length and a YAML alias bomb are
bounded before any work, each one error line; the Snakefile's errors are one line, not followed by Snakemake's
stack; an OBJ error names the file and line, never the line's words."""
from __future__ import annotations

import subprocess
import sys
import time

import pytest

from pipeline.core.config import load_config
from pipeline.core.errors import PipelineError
from pipeline.core.meshio import load_mesh
from pipeline.workflow_plan import plan, targeted_scenes
from hostile import REPO

SNAKEMAKE = [sys.executable, "-m", "snakemake", "-n", "--cores", "1", "-s", str(REPO / "Snakefile")]
# A two-joint clip of 1000 frames whose header claims 100 s a frame: 27.75 hours, 5.99 M frames at 60 frames/s.
SLOW_CLIP = ("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
             "Yrotation\nJOINT Head\n{\nOFFSET 0 1.7 0\nCHANNELS 0\n}\n}\nMOTION\nFrames: 1000\nFrame Time: 100\n"
             + "0 0 0 0 0 0\n" * 1000)


def _shipped() -> dict:
    return load_config(REPO / "workflow_config.yaml")


def _plan_error(config: dict, capsys) -> str:
    with pytest.raises(PipelineError) as refused:
        plan(config)
    assert capsys.readouterr().err == ""
    return str(refused.value)


def test_a_held_out_clip_cannot_bypass_the_frames_bound(tmp_path, capsys):
    (tmp_path / "slow.bvh").write_text(SLOW_CLIP)
    config = _shipped()
    config["scenes"]["pants"]["drivers"]["mannequin"]["test_clips"] = [{"bvh": str(tmp_path / "slow.bvh")}]
    message = _plan_error(config, capsys)
    assert "'pants' sequence 'held_out_000': 5,994,030 frames, more than 100,000" in message, message


@pytest.mark.parametrize("key", ["settle_frames", "blend_frames"])
def test_settle_and_blend_frames_are_bounded(key, capsys):
    config = _shipped()
    config["scenes"]["pants"]["drivers"]["mannequin"][key] = 10**6
    assert f"{key}: 1000000 is greater than the maximum of 100000" in _plan_error(config, capsys)


def test_a_large_plan_is_stated_and_refused_unless_allowed(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)    # no results/pants/subdiv.h5 here
    config = _shipped()
    config["profiles"]["cpu"]["scenes"]["pants"]["sequences"] = 2000
    assert "'pants' plans 6,012 jobs" in _plan_error(config, capsys)
    plan({**config, "allow_large": True})
    assert capsys.readouterr().err.splitlines() == [
        "plan: 8 scene(s); the largest, pants: 6,012 jobs, 420,210 frames simulated a level (limits 1,000 and "
        "500,000 a scene)", "disk: known for pants once its mesh is made (`snakemake results/pants/subdiv.h5`, "
        "seconds)"]


@pytest.mark.parametrize("targets, scenes", [((), ["pants"]), (["results/flag/", "results/flag/report.md"], ["flag"]),
                                             (["results/multi/", "results/./tshirt/x"], ["tshirt"]),
                                             (["all"], [])])
def test_the_disk_is_said_for_the_scenes_the_targets_name(targets, scenes):
    assert targeted_scenes(targets, _shipped()["scenes"], "pants") == scenes


def test_a_million_sequences_is_refused_by_the_schema(capsys):
    config = _shipped()
    config["profiles"]["cpu"]["scenes"]["pants"]["sequences"] = 10**6
    assert "1000000 is greater than the maximum of 10000" in _plan_error(config, capsys)


def test_a_yaml_alias_bomb_is_refused_at_once(tmp_path):
    lines = ["_bomb:", "  a0: &a0 [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]"]
    lines += [f"  a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 9)]
    (tmp_path / "bomb.yaml").write_text("\n".join(lines) + "\n")
    start = time.perf_counter()
    done = subprocess.run(SNAKEMAKE + ["--configfile", str(tmp_path / "bomb.yaml")], capture_output=True, text=True,
                          cwd=tmp_path, timeout=60)
    assert time.perf_counter() - start < 30
    assert done.returncode == 2 and done.stderr.splitlines() == [
        "error: workflow config: more than 100,000 values once YAML aliases are expanded (an alias repeating "
        "another many times over?)"], done.stderr


def test_a_config_error_in_the_snakefile_is_one_line(tmp_path):
    (tmp_path / "bad.yaml").write_text("scenes: {pants: {mesh: {files: x}}}\n")
    done = subprocess.run(SNAKEMAKE + ["--configfile", str(tmp_path / "bad.yaml")], capture_output=True, text=True,
                          cwd=tmp_path, timeout=60)
    assert done.returncode == 2
    assert done.stderr.splitlines() == ["error: workflow config: unknown key 'files' in scenes.pants.mesh"]


def test_an_obj_error_never_quotes_the_line(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 secret-words\n")
    with pytest.raises(PipelineError) as refused:
        load_mesh(tmp_path / "m.obj")
    assert "line 4" in str(refused.value) and "secret" not in str(refused.value)



def test_the_plan_is_said_once_a_run(tmp_path):
    """Snakemake parses the Snakefile again in each process it spawns for a job (rules with `run:`): the cost
    line comes from the main process alone."""
    command = [sys.executable, "-m", "snakemake", "--cores", "1", "-s", str(REPO / "Snakefile"),
               "results/patch/simulation.json"]
    done = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert [line for line in done.stderr.splitlines() if line.startswith("plan:")] == [
        "plan: 8 scene(s); the largest, pants: 24 jobs, 1,050 frames simulated a level (limits 1,000 and "
        "500,000 a scene)"]
