"""operators.h5, written by the `operators` stage: per mesh level the convolution tables and the pooling maps
to the next level (docs/artifacts.md, section "operators.h5"); read back as the network's mesh hierarchy."""
from __future__ import annotations

import json
import os
from typing import TYPE_CHECKING, Any, Mapping

import h5py
import numpy as np

from meshops import Level, parse_conv_kind
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import SOURCE_MESH, atomic_h5, check_same_mesh, open_artifact, read_indices

if TYPE_CHECKING:
    from model.mesh_hierarchy import MeshHierarchy

STAGE = "operators"
INDEX_CONVENTION = ("conv tables: vertex id + 1, 0 = the zero-padding slot; pool, unpool, fixed_vertex, "
                    "geodesic_sources: plain 0-based vertex ids")


def write_operators(path: str | os.PathLike, levels: list[Level], config: Mapping[str, Any],
                    source_mesh: str | None) -> None:
    """Write the levels of a mesh derived from the low-res rest mesh whose `mesh_fingerprint` is `source_mesh`
    (None for a mesh of unknown origin, an OBJ file: the artifact then carries no attr to compare)."""
    with atomic_h5(path, STAGE, config) as f:
        if source_mesh is not None:
            f.attrs[SOURCE_MESH] = source_mesh
        f.attrs["n_levels"] = len(levels)
        f.attrs["conv"] = json.dumps(list(levels[0].conv))
        f.attrs["index_convention"] = INDEX_CONVENTION
        for index, level in enumerate(levels):
            group = f.create_group(f"levels/{index}")
            group.create_dataset("vertices", data=level.vertices.astype(np.float32))
            group["vertices"].attrs["unit"] = "scene unit (material space), y up"
            group.create_dataset("faces", data=level.faces.astype(np.int32))
            group.attrs["fixed_vertex"] = level.fixed_vertex
            group.attrs["geodesic_method"] = level.geodesic_method
            group.create_dataset("geodesic_sources", data=level.geodesic_sources.astype(np.int32))
            for name, table in level.conv.items():
                kind, length = parse_conv_kind(name)
                dataset = group.create_dataset(f"conv/{name}", data=table.astype(np.int32))
                dataset.attrs["kind"] = kind
                dataset.attrs["filter_length"] = length
                dataset.attrs["padding_index"] = 0
                if name in level.ec_fallbacks:
                    dataset.attrs["rc_fallback_vertices"] = level.ec_fallbacks[name]
            if level.coarsening is not None:
                group.create_dataset("pool", data=level.coarsening.pool.astype(np.int32))
                group.create_dataset("unpool", data=level.coarsening.unpool.astype(np.int32))
                group.attrs["collapsed_edges"] = level.coarsening.collapsed
                group.attrs["largest_quadric_error"] = level.coarsening.largest_error


def load_hierarchy(path: str | os.PathLike, conv: str, n_levels: int, faces: np.ndarray | None = None,
                   dataset: str | os.PathLike | None = None) -> MeshHierarchy:
    """Levels 0..n_levels-1 of an operators artifact with the `conv` tables; with `faces` (those of the artifact
    `dataset`), check that level 0 is that mesh: the same faces and, where both artifacts record one, the same
    `source_mesh` (the operators of a moved copy of the mesh have its faces, but tables of other geometry)."""
    # Imported here, not at the top: torch takes seconds to load, and the stage that writes this file needs none.
    from model.mesh_hierarchy import mesh_hierarchy

    if dataset is not None:
        check_same_mesh(path, dataset)
    with open_artifact(path) as f:
        if "levels" not in f:
            raise PipelineError(f"{path}: no 'levels' group (not an operators file)")
        available = len(f["levels"])
        if n_levels > available:
            raise PipelineError(f"{path}: the architecture needs {n_levels} mesh levels ({n_levels - 1} poolings), "
                                f"the file has {available} (rebuild the operators with --levels {n_levels - 1} "
                                f"or more)")
        if f"levels/0/conv/{conv}" not in f:
            kinds = sorted(f["levels/0/conv"]) if "levels/0/conv" in f else []
            raise PipelineError(f"{path}: no '{conv}' convolution tables (the file has {', '.join(kinds) or 'none'})")
        counts = [_vertex_count(f, i) for i in range(n_levels)]
        tables = [read_indices(f, f"levels/{i}/conv/{conv}", counts[i] + 1, shape=(counts[i], None))
                  for i in range(n_levels)]
        pools = [read_indices(f, f"levels/{i}/pool", counts[i], shape=(counts[i + 1], 2))
                 for i in range(n_levels - 1)]
        unpools = [read_indices(f, f"levels/{i}/unpool", counts[i + 1], shape=(counts[i],))
                   for i in range(n_levels - 1)]
        level0_faces = read_indices(f, "levels/0/faces", counts[0], shape=(None, 3))
    if faces is not None and not np.array_equal(level0_faces, faces):
        raise PipelineError(f"{path}: level 0 is not the dataset's mesh (different faces)")
    try:
        return mesh_hierarchy(tables, pools, unpools)
    except ValueError as err:
        raise PipelineError(f"{path}: {err}") from None


def _vertex_count(f: h5py.File, level: int) -> int:
    """Vertices of a level, from the shape of its `vertices` dataset: the bound its index tables must keep."""
    name = f"levels/{level}/vertices"
    if not isinstance(f.get(name), h5py.Dataset) or len(f[name].shape) != 2:
        raise PipelineError(f"{f.filename}: missing dataset '{name}' of shape (V_{level}, 3)")
    return int(f[name].shape[0])
