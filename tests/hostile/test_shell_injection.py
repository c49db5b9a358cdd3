"""Item 1 of issue 13: config strings never reach a shell. Scene names become folders, wildcards and words of
shell commands, so only letters, digits, `_`, `.` and `-` are accepted; every other config value travels in
settings.json (tests/pipeline/test_workflow.py::test_no_config_value_reaches_a_shell_command plants a command
substitution in the architecture and checks the planned commands)."""
from __future__ import annotations

import subprocess

import pytest
import yaml

from hostile import REPO, assert_refused, files_in, run_stage
from workflow_runs import SNAKEMAKE

# Each would create `pwned` in the working directory if a shell ever saw it unquoted.
BAD_NAMES = ["pa`touch pwned`", "$(touch pwned)", "x;touch pwned", "../escape", "-flag"]


def _config_with_scene(folder: Path, name: str) -> Path:
    config = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
    config["scenes"][name] = config["scenes"]["patch"]
    path = folder / "evil.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


@pytest.mark.parametrize("name", BAD_NAMES)
def test_scene_name_with_shell_syntax_is_one_clear_error(tmp_path, name):
    config = _config_with_scene(tmp_path, name)
    before = files_in(tmp_path)
    run = run_stage("settings", config, "patch", tmp_path / "settings.json", cwd=tmp_path)
    assert_refused(run, "evil.yaml", "scenes", name, folder=tmp_path, before=before)


def test_plain_scene_names_are_accepted(tmp_path):
    config = _config_with_scene(tmp_path, "pants_v2.1-b")
    run = run_stage("settings", config, "pants_v2.1-b", tmp_path / "settings.json", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "settings.json").is_file()


def test_workflow_with_such_a_scene_stops_before_any_job(tmp_path):
    config = _config_with_scene(tmp_path, BAD_NAMES[0])
    run = subprocess.run([*SNAKEMAKE, "--cores", "1", "--snakefile",
                          str(REPO / "Snakefile"), "--directory", str(tmp_path), f"results/{BAD_NAMES[0]}/scene.h5",
                          "--configfile", str(config)], capture_output=True, text=True, timeout=300)
    assert run.returncode != 0
    assert f"scenes: '{BAD_NAMES[0]}' does not match" in run.stdout + run.stderr
    assert not (tmp_path / "pwned").exists() and not (tmp_path / "results").exists()
