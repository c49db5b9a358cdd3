"""Item 10 of issue 13: an output the file system will not take (its path is a folder, a folder on its way is a
regular file, the folder is read-only) is one error naming the output, from the one safe-write helper every
stage writes through (pipeline.core.h5), and leaves no temporary file behind. Once each was an OSError
traceback from mkdir, mkstemp or the final rename."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from hostile import REPO, assert_refused, files_in, run_stage


def _folder_at_output(folder: Path) -> Path:
    (folder / "out.h5").mkdir()
    return folder / "out.h5"


def _file_on_the_way(folder: Path) -> Path:
    (folder / "notes.txt").write_text("a file, not a folder")
    return folder / "notes.txt" / "sub" / "out.h5"


# name: (makes the unusable output path in a folder, words the error must hold)
UNUSABLE = {
    "output is a folder": (_folder_at_output, "it is a folder"),
    "a folder on the way is a file": (_file_on_the_way, "notes.txt is a file, not a folder"),
}


@pytest.mark.parametrize("case", UNUSABLE)
@pytest.mark.parametrize("stage", ["subdivide", "config"])
def test_an_unusable_output_path_is_one_clear_error(valid, tmp_path, case, stage):
    """subdivide writes HDF5 (atomic_h5), config writes settings.json (atomic_write)."""
    make, words = UNUSABLE[case]
    out = make(tmp_path)
    before = files_in(tmp_path)
    if stage == "subdivide":
        run = run_stage("subdivide", valid / "subdiv.h5", out, "--levels", "1", "--quiet")
    else:
        run = run_stage("settings", REPO / "workflow_config.yaml", "patch", out)
    assert_refused(run, f"{out}: cannot write the output", words, folder=tmp_path, before=before)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_output_folder_is_one_clear_error(valid, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        run = run_stage("subdivide", valid / "subdiv.h5", locked / "subdiv.h5", "--levels", "1", "--quiet")
        assert_refused(run, f"{locked / 'subdiv.h5'}: cannot write the output", "Permission denied")
        assert files_in(locked) == set()
    finally:
        locked.chmod(0o755)
