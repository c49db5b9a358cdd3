"""Sequences of the waving sheet (stage_inputs) dressed as a motion library's windows: each folder holds the runs
and a scene.h5 that says which sequence it is, its role and, for a library window, the window it plays (attr
`library_window`, as the scene stage writes it), so that the dataset stage gathers them as a library scene's
sequences without a mannequin or a simulation. What the split and evaluation-by-motion-kind tests build on."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.artifacts.scene import LIBRARY_WINDOW
from pipeline.core.h5 import atomic_h5, write_dropped
from stage_inputs import SIM_CONFIG, write_waving_sheet

FRAME_TIME = SIM_CONFIG["solver"]["dt"]      # seconds between frames of the sheet's runs


def window(file: str, subject: str, category: str, start: float, end: float) -> dict:
    """A library window as scene.h5 describes it (scenes.library.LibraryWindow.describe)."""
    return {"file": file, "subject": subject, "category": category, "description": "", "start": start, "end": end,
            "frame_time": FRAME_TIME}


def write_sheet_sequence(root: Path, name: str, role: str, played: dict | None, n_frames: int,
                         amplitude: float = 1.0) -> Path:
    """root/name: the sheet waving for `n_frames` frames (its motion scaled by `amplitude`, so that sequences
    differ) and its scene.h5; root/subdiv.h5 beside it."""
    write_waving_sheet(root, runs_folder=name, n_frames=n_frames,
                       transform=lambda x, f: x * np.array([1.0, 1.0, amplitude]))
    with atomic_h5(root / name / "scene.h5", "scene") as f:
        f.attrs.update(sequence=name, role=role,
                       **({LIBRARY_WINDOW: json.dumps(played, sort_keys=True)} if played else {}))
        f["rest/vertices"] = np.zeros((3, 3))
        f["pins/targets"] = np.zeros((n_frames, 0, 3))
    return root / name


def write_dropped_sequence(root: Path, name: str, reason: str) -> Path:
    """root/name as the scene stage leaves a window it could not play: its scene.h5 stands for it, with the
    reason."""
    (root / name).mkdir(parents=True, exist_ok=True)
    write_dropped(root / name / "scene.h5", "scene", None, reason, {"sequence": name})
    return root / name
