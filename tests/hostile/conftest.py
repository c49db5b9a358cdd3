"""The valid artifacts every hostile test spoils a copy of (built once per session)."""
from __future__ import annotations

from pathlib import Path

import pytest

from hostile import dataset_command, write_simulations
from pipeline import dataset, operators
from pipeline.core import cli


@pytest.fixture(scope="session")
def valid(tmp_path_factory) -> Path:
    """subdiv.h5, sequence/sim_low.h5, sequence/sim_high.h5, operators.h5 (RC7, 4 levels) and dataset.h5 of a
    small sheet."""
    folder = tmp_path_factory.mktemp("valid")
    write_simulations(folder)
    cli.run(operators.main, [str(folder / "subdiv.h5"), str(folder / "operators.h5"), "--conv", "RC7", "--levels",
                             "3", "--quiet"])
    cli.run(dataset.main, [str(a) for a in dataset_command(folder / "subdiv.h5", folder / "dataset.h5", folder)])
    return folder
