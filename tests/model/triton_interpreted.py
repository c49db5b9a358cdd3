"""Running a test file's kernels under Triton's interpreter on the CPU: TRITON_INTERPRET=1 must be set before
Triton is imported, so the file runs itself in a subprocess (its `__main__` prints its errors as JSON on its last
line) and the test reads them back."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path


def interpreted_errors(test_file: str) -> dict[str, float]:
    """The JSON dict `test_file` prints last when run as a script with TRITON_INTERPRET=1."""
    here = Path(test_file).parent
    env = dict(os.environ, TRITON_INTERPRET="1",
               PYTHONPATH=os.pathsep.join([str(here), str(here.parents[1]), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, test_file], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.splitlines()[-1])
