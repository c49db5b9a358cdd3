"""What drops a library window's run (pipeline.solvers.xpbd.tangle_check) and how a dropped artifact reads back
(pipeline.core.h5.write_dropped / dropped_reason)."""
import h5py
import numpy as np
import pytest

from geometry.mesh import unique_edges
from geometry.shapes import grid_patch
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import dropped_reason, write_dropped
from pipeline.solvers.xpbd import TANGLE_EDGE_SHARE, TANGLE_STRETCH, tangle_check


def stretched(vertices: np.ndarray, faces: np.ndarray, share: float) -> np.ndarray:
    """Frames (3, V, 3) of the mesh at rest but, in frame 1, about `share` of its edges twice as long: the vertices
    of one corner pulled out along z (their edges to the rest stretch, those among them do not)."""
    frames = np.repeat(vertices[None], 3, axis=0)
    edges = unique_edges(faces)
    order = np.argsort(vertices[:, 0] + vertices[:, 1])
    for k in range(1, len(order)):
        moved = np.zeros(len(vertices), bool)
        moved[order[:k]] = True
        if (moved[edges[:, 0]] != moved[edges[:, 1]]).mean() >= share:
            break
    frames[1, moved, 2] += 3.0 * np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1).max()
    return frames


def test_a_run_is_tangled_only_where_a_share_of_its_edges_is_pulled_far_beyond_rest():
    vertices, faces = grid_patch(12, 12)
    tangled = tangle_check(vertices, faces)
    assert tangled(np.repeat(vertices[None], 4, axis=0)) == ""
    assert tangled(np.repeat(vertices[None] * (TANGLE_STRETCH * 0.99), 2, axis=0)) == ""   # all edges, but short
    reason = tangled(stretched(vertices, faces, 2 * TANGLE_EDGE_SHARE))
    assert reason.startswith("tangled: at frame 1 ") and "beyond 1.5x" in reason
    assert tangled(stretched(vertices, faces, TANGLE_EDGE_SHARE / 3)) == ""


def test_a_dropped_artifact_says_why_and_an_ordinary_one_does_not(tmp_path):
    write_dropped(tmp_path / "sim_low.h5", "simulate_low", {"scene": "pants"}, "tangled: at frame 3 ...",
                  {"sequence": "train_001-01-01_w00"})
    assert dropped_reason(tmp_path / "sim_low.h5") == "tangled: at frame 3 ..."
    with h5py.File(tmp_path / "plain.h5", "w") as f:
        f.attrs["stage"] = "scene"
    assert dropped_reason(tmp_path / "plain.h5") is None
    with pytest.raises(PipelineError, match="input file does not exist"):
        dropped_reason(tmp_path / "missing.h5")
