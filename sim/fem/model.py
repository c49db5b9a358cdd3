"""The static model of a quasi-static FEM run (NVIDIA Newton's Model): a tetrahedral volume, its material and
solver settings, the nodes the bones drive (Dirichlet) and the surface embedded in it, whose vertices a run
stores. Where the driven nodes are comes per frame (FemInputs)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from geometry.tets import tet_volumes
from sim.fem.settings import FemSettings

# A tet whose rest volume is at most this fraction of the mean tet volume is degenerate: its inverse rest shape
# (Dm^-1) and so its stiffness would blow up.
MIN_VOLUME_FRACTION = 1.0e-6
# Barycentric weights of an embedded vertex must sum to one within this.
WEIGHT_SUM_TOLERANCE = 1.0e-6



@dataclass(frozen=True, eq=False)
class FemModel:
    """A tet mesh and what holds it, shared by every world a solver steps. Checked when made: a ValueError names
    the first field that does not fit. Every tet must be positively oriented and not degenerate, every node must
    belong to a tet, and at least one node must be driven (a body held by nothing has no quasi-static answer).
    `embedding` places each output vertex in a tet: (tet ids (S,), barycentric weights (S, 4)); without it a run
    stores the nodes themselves."""

    rest_vertices: np.ndarray                       # (N, 3) nodes
    tets: np.ndarray                                # (T, 4) node ids, positively oriented
    settings: FemSettings = field(default_factory=FemSettings)
    driven: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))   # (D,) node ids
    embedding: tuple[np.ndarray, np.ndarray] | None = None

    def __post_init__(self):
        rest, tets = np.asarray(self.rest_vertices), np.asarray(self.tets)
        if rest.ndim != 2 or rest.shape[1] != 3 or len(rest) < 4 or rest.dtype.kind not in "fiu" \
                or not np.isfinite(rest).all():
            raise ValueError(f"rest_vertices must be (N, 3) finite numbers, N >= 4; got {rest.dtype}{rest.shape}")
        n = len(rest)
        if tets.ndim != 2 or tets.shape[1] != 4 or len(tets) == 0 or tets.dtype.kind not in "iu" \
                or tets.min() < 0 or tets.max() >= n:
            raise ValueError(f"tets must be (T, 4) ids of the {n} nodes; got {tets.dtype}{tets.shape}")
        volumes = tet_volumes(rest, tets)
        bad = np.flatnonzero(volumes <= MIN_VOLUME_FRACTION * np.abs(volumes).mean())
        if len(bad):
            raise ValueError(f"{len(bad)} tets are inverted or degenerate at rest (first: tet {bad[0]}, volume "
                             f"{volumes[bad[0]]:.3g})")
        unused = np.setdiff1d(np.arange(n), tets.ravel())
        if len(unused):
            raise ValueError(f"{len(unused)} nodes belong to no tet (first: node {unused[0]})")
        driven = np.asarray(self.driven)
        if driven.ndim != 1 or driven.size == 0 or driven.dtype.kind not in "iu" or driven.min() < 0 \
                or driven.max() >= n or len(np.unique(driven)) != len(driven):
            raise ValueError(f"driven must be (D,) distinct ids of the {n} nodes, D >= 1; got "
                             f"{driven.dtype}{driven.shape}")
        object.__setattr__(self, "rest_vertices", rest.astype(np.float64))
        object.__setattr__(self, "tets", tets.astype(np.int64))
        object.__setattr__(self, "driven", driven.astype(np.int64))
        object.__setattr__(self, "embedding", self._checked_embedding(len(tets)))

    def _checked_embedding(self, n_tets: int) -> tuple[np.ndarray, np.ndarray] | None:
        if self.embedding is None:
            return None
        tet_ids, weights = (np.asarray(a) for a in self.embedding)
        if tet_ids.ndim != 1 or tet_ids.size == 0 or tet_ids.dtype.kind not in "iu" or tet_ids.min() < 0 \
                or tet_ids.max() >= n_tets:
            raise ValueError(f"embedding tet ids must be (S,) ids of the {n_tets} tets; got "
                             f"{tet_ids.dtype}{tet_ids.shape}")
        if weights.shape != (len(tet_ids), 4) or not np.isfinite(weights).all() \
                or np.abs(weights.sum(axis=1) - 1.0).max() > WEIGHT_SUM_TOLERANCE:
            raise ValueError(f"embedding weights must be ({len(tet_ids)}, 4) finite and sum to 1 per vertex")
        return tet_ids.astype(np.int64), weights.astype(np.float64)

    @property
    def output_count(self) -> int:
        """Vertices a run stores: the embedded surface's, or the nodes'."""
        return len(self.rest_vertices) if self.embedding is None else len(self.embedding[0])
