"""The sequences of a tiny pants scene with made-up runs, as the dataset stage gathers them: two training sequences
and the held-out one, each with its real scene.h5, and their subdivision. What the dataset-sequence and the
decoder-task tests build their datasets from."""
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import yaml

from geometry.loop_subdivision import loop_subdivide
from pipeline.artifacts.scene import write_scene
from pipeline.core.config import resolve_scene
from pipeline.core.h5 import atomic_h5, write_csr
from scenes.registry import build_scene

CONFIG = yaml.safe_load((Path(__file__).resolve().parents[2] / "workflow_config.yaml").read_text())
FRAMES, SETTLE = 24, 3
SEQUENCES = ("train_000", "train_001", "held_out_000")


def write_sequence(folder: Path, settings: dict, name: str, S) -> np.ndarray:
    """A sequence folder: its real scene.h5 and made-up runs (the rest mesh waving, high-res wrinkles on S x_low)
    that differ per sequence. Returns the low-res positions."""
    scene = build_scene(settings, name)
    write_scene(folder / "scene.h5", scene, settings)
    rest, faces = scene.rest.vertices, scene.rest.faces
    t = np.arange(scene.n_frames)[:, None, None] + 100 * SEQUENCES.index(name)
    low = rest + 0.01 * np.sin(0.3 * t + rest[None, :, :1] * 5)
    high = np.stack([S @ x for x in low]) + 0.002 * np.cos(0.2 * t)
    high_faces = loop_subdivide(rest, faces, 1)[1]
    for level, positions, f in (("low", low, faces), ("high", high, high_faces)):
        with atomic_h5(folder / f"sim_{level}.h5", f"simulate_{level}", settings) as out:
            out["positions"], out["faces"] = positions.astype(np.float32), f.astype(np.int32)
    return low


def write_pants_sequences(root: Path) -> tuple[sp.csr_matrix, dict[str, np.ndarray]]:
    """root/subdiv.h5 (one Loop subdivision level of the tiny pants, FRAMES frames, SETTLE settle frames) and a
    folder per sequence of SEQUENCES (write_sequence). Returns S and each sequence's low-res positions."""
    settings = resolve_scene(CONFIG, "pants", "cpu")
    settings.update(frames=FRAMES)
    settings["mesh"]["max_edge"] = 0.3
    settings["drivers"]["mannequin"].update(settle_frames=SETTLE, blend_frames=4)
    rest = build_scene(settings, "train_000").rest
    S, high_faces = loop_subdivide(rest.vertices, rest.faces, 1)
    with atomic_h5(root / "subdiv.h5", "subdivide") as out:
        write_csr(out, "S", S)
        out["vertices"], out["faces"] = S @ rest.vertices, high_faces.astype(np.int32)
    return S, {name: write_sequence(root / name, settings, name, S) for name in SEQUENCES}
