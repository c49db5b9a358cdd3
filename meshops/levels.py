"""The whole operator precompute: a hierarchy of coarsened meshes with convolution tables on every level."""
from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from meshops.conv import conv_table, spiral_depth
from meshops.neighbourhood import build_neighbourhood
from meshops.pooling import Coarsening, collapse_pass
from geometry.mesh import validate_mesh

CONV_KINDS = ("RC", "EC", "SP", "SPD")
DEFAULT_CONV = ("RC13", "EC13", "SP13", "SPD13")
DEFAULT_POOLING_STEPS = 10
# In squared mean edge lengths: roughly a midpoint 3 % of an edge off the planes of its dozen neighbouring faces.
DEFAULT_QUADRIC_THRESHOLD = 0.01


@dataclass
class Level:
    vertices: np.ndarray                 # (V, 3) float64 material-space positions
    faces: np.ndarray                    # (F, 3) int64
    fixed_vertex: int                    # paper eq. 2
    geodesic_sources: np.ndarray         # the fixed vertex, then one per further connected component
    geodesic_method: str                 # "heat", or "dijkstra" where the heat step underflowed
    conv: dict[str, np.ndarray] = field(default_factory=dict)   # name (e.g. "RC13") -> (V, L) int32, ids + 1
    ec_fallbacks: dict[str, int] = field(default_factory=dict)  # EC name -> vertices sampled on the RC ring
    coarsening: Coarsening | None = None  # the map to the next level; None on the coarsest
    seconds: dict[str, float] = field(default_factory=dict)     # wall time per part, for benchmarks


def parse_conv_kind(name: str) -> tuple[str, int]:
    """'RC13' -> ('RC', 13); the filter length counts the vertex itself, so it must be at least 2."""
    match = re.fullmatch(r"(RC|EC|SPD|SP)(\d+)", name)
    if not match or int(match.group(2)) < 2:
        raise ValueError(f"convolution {name!r} is not KIND+LENGTH with KIND in {', '.join(CONV_KINDS)} "
                         "and LENGTH >= 2 (e.g. RC13)")
    return match.group(1), int(match.group(2))


def parse_conv_kinds(names: Sequence[str]) -> list[tuple[str, int]]:
    """Parse a list of table names, refusing an empty list and repeats."""
    if not names:
        raise ValueError("no convolution named")
    if len(set(names)) < len(names):
        raise ValueError(f"a convolution is named twice in {', '.join(names)}")
    return [parse_conv_kind(name) for name in names]


def build_operators(vertices: np.ndarray, faces: np.ndarray, conv: Sequence[str] = DEFAULT_CONV,
                    pooling_steps: int = DEFAULT_POOLING_STEPS,
                    quadric_threshold: float = DEFAULT_QUADRIC_THRESHOLD,
                    progress: Callable[[int, Level], None] | None = None) -> list[Level]:
    """Levels 0..pooling_steps: level 0 is the input mesh in its own vertex order, each next one a collapse pass
    of the previous (the identity once nothing can collapse). Raises ValueError on an unusable mesh or spec."""
    kinds = parse_conv_kinds(conv)
    if pooling_steps < 0:
        raise ValueError(f"pooling steps must be >= 0, got {pooling_steps}")
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    validate_mesh(vertices, faces)
    faces = faces.astype(np.int64)
    depth = max([spiral_depth(length, 2 if kind == "SPD" else 1) for kind, length in kinds if kind.startswith("SP")],
                default=0)

    levels = []
    for index in range(pooling_steps + 1):
        started = time.perf_counter()
        nb = build_neighbourhood(vertices, faces, depth)
        level = Level(vertices, faces, nb.fixed_vertex, nb.geodesic_sources, nb.geodesic_method)
        level.seconds["neighbourhood"] = time.perf_counter() - started
        for (kind, length), name in zip(kinds, conv):
            started = time.perf_counter()
            level.conv[name], fallbacks = conv_table(nb, kind, length)
            if kind == "EC":
                level.ec_fallbacks[name] = fallbacks
            level.seconds[name] = time.perf_counter() - started
        if index < pooling_steps:
            started = time.perf_counter()
            level.coarsening = collapse_pass(vertices, faces, quadric_threshold)
            level.seconds["pooling"] = time.perf_counter() - started
            vertices, faces = level.coarsening.vertices, level.coarsening.faces
        levels.append(level)
        if progress is not None:
            progress(index, level)
    return levels
