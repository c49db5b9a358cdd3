"""pipeline.core.torch_setup.set_arithmetic sets torch's deterministic flag without the ~1 s import of Inductor that
torch.use_deterministic_algorithms makes (every train and evaluate process pays it otherwise), and keeps
Inductor's copy of the flag in step where Inductor is loaded, as the public call does."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import torch

from pipeline.core.torch_setup import set_arithmetic

REPO = Path(__file__).resolve().parents[2]


def test_the_flag_is_set_and_inductor_is_not_loaded_for_it():
    code = ("import sys, torch\nfrom pipeline.core.torch_setup import set_arithmetic\nset_arithmetic(True, False)\n"
            "print(torch.are_deterministic_algorithms_enabled(), 'torch._inductor' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["True", "False"]


def test_a_loaded_inductor_keeps_its_copy_of_the_flag():
    import torch._inductor.config as inductor
    was = torch.are_deterministic_algorithms_enabled(), inductor.deterministic
    try:
        for mode in (True, False, True):
            set_arithmetic(mode, False)
            assert torch.are_deterministic_algorithms_enabled() is mode and inductor.deterministic is mode
    finally:
        torch.use_deterministic_algorithms(was[0])
        inductor.deterministic = was[1]
