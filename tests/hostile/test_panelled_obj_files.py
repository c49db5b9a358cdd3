"""Item 5 of issue 13: a garment modelled as separate panels, exported the way artists' OBJ files are (one group
of vertices and faces per panel, seam vertices duplicated at the same positions), goes through the subdivide
and operators stages. Once it ended the operators stage in a traceback (a NaN assignment cost where a seam copy
of a vertex lay within its own three-ring)."""
from __future__ import annotations

import h5py
import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from geometry.mesh import unique_edges
from hostile import run_stage
from scenes.garments import make_garment


def write_panels_obj(path, vertices: np.ndarray, faces: np.ndarray) -> int:
    """An OBJ with one group per connected piece, each listing its own vertices then its faces, as a modelling
    tool exports separate panels. Returns the number of panels."""
    edges = unique_edges(faces)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(vertices),) * 2)
    n_panels, piece = csgraph.connected_components(graph, directed=False)
    lines, written = [], 0
    for panel in range(n_panels):
        members = np.flatnonzero(piece == panel)
        number = np.zeros(len(vertices), dtype=np.int64)
        number[members] = written + 1 + np.arange(len(members))
        lines.append(f"g panel_{panel}")
        lines += [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in vertices[members]]
        lines += [f"f {a} {b} {c}" for a, b, c in number[faces[piece[faces[:, 0]] == panel]]]
        written += len(members)
    path.write_text("\n".join(lines) + "\n")
    return n_panels


def test_a_panelled_garment_obj_is_subdivided_and_gets_finite_operators(tmp_path):
    garment = make_garment("cape", max_edge=0.08, panels=True)
    mesh = tmp_path / "cape_panels.obj"
    assert write_panels_obj(mesh, garment.vertices, garment.faces) >= 6
    subdivided = run_stage("subdivide", mesh, tmp_path / "subdiv.h5", "--levels", "1", "--quiet")
    assert subdivided.returncode == 0, subdivided.stderr[-3000:]
    for source in (mesh, tmp_path / "subdiv.h5"):
        out = tmp_path / f"operators_{source.stem}.h5"
        run = run_stage("operators", source, out, "--conv", "RC9,EC9,SP9,SPD9", "--levels", "10", "--quiet")
        assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr[-3000:]
        with h5py.File(out) as f:
            for index in range(11):
                level = f[f"levels/{index}"]
                n = len(level["vertices"])
                assert np.isfinite(level["vertices"][()]).all()
                for name in ("RC9", "EC9", "SP9", "SPD9"):
                    table = level[f"conv/{name}"][()]
                    assert table.min() >= 0 and table.max() <= n
