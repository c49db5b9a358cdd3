"""The elastic energy of every world's tet mesh on one Warp device: per-world energies, the gradient and the
assembled (projected) Hessian as a block-sparse matrix of 3 x 3 blocks (warp.sparse).

Arrays are world-major like the cloth solver's: node i of world w is row w N + i, and a kernel over the tets of
all worlds finds its world as tid // T. The driven nodes are Dirichlet nodes: their gradient rows are zero and
their Hessian rows and columns are the identity's, so a Newton step leaves them where the frame put them.
"""
from __future__ import annotations

import numpy as np
import warp as wp
import warp.sparse as wps

from sim.fem.model import FemModel
from sim.fem.neohookean import energy_density, stress, stress_derivative

mat33d = wp.mat33d

# Loops of up to 3 trips are unrolled, the Hessian's loops over the tet's 4 x 4 node pairs are not: fully unrolled
# (1,296 products of dP/dF's entries) the module took 20-38 s to compile on the 2-core CPU, 10 s so, and its
# assembly ran as fast (38 ms for 18k tets either way, alternated).
wp.set_module_options({"max_unroll": 3})


@wp.func
def shape_gradient(dm_inv: wp.mat33d, a: int):
    """d F / d x_a as the row vector g_a: F = sum_a x_a g_a^T. Row a - 1 of Dm^-1 for a >= 1, minus their sum
    for node 0."""
    if a == 0:
        return -(dm_inv[0] + dm_inv[1] + dm_inv[2])
    return dm_inv[a - 1]


@wp.func
def deformation_gradient(x: wp.array(dtype=wp.vec3d), tet: wp.vec4i, offset: int, dm_inv: wp.mat33d):
    x0 = x[offset + tet[0]]
    e1 = x[offset + tet[1]] - x0
    e2 = x[offset + tet[2]] - x0
    e3 = x[offset + tet[3]] - x0
    Ds = wp.mat33d(e1[0], e2[0], e3[0], e1[1], e2[1], e3[1], e1[2], e2[2], e3[2])
    return Ds * dm_inv


@wp.kernel
def element_energy(x: wp.array(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i), dm_inv: wp.array(dtype=mat33d),
                   volume: wp.array(dtype=wp.float64), mu: wp.float64, lam: wp.float64, n_tets: int,
                   n_nodes: int, energy: wp.array(dtype=wp.float64)):
    tid = wp.tid()
    world = tid // n_tets
    t = tid - world * n_tets
    F = deformation_gradient(x, tets[t], world * n_nodes, dm_inv[t])
    wp.atomic_add(energy, world, volume[t] * energy_density(F, mu, lam))


@wp.kernel
def element_gradient(x: wp.array(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i), dm_inv: wp.array(dtype=mat33d),
                     volume: wp.array(dtype=wp.float64), mu: wp.float64, lam: wp.float64, n_tets: int,
                     n_nodes: int, driven: wp.array(dtype=wp.int32), gradient: wp.array(dtype=wp.vec3d)):
    tid = wp.tid()
    world = tid // n_tets
    t = tid - world * n_tets
    tet = tets[t]
    offset = world * n_nodes
    F = deformation_gradient(x, tet, offset, dm_inv[t])
    P = volume[t] * stress(F, mu, lam)
    for a in range(4):
        if driven[tet[a]] == 0:
            wp.atomic_add(gradient, offset + tet[a], P * shape_gradient(dm_inv[t], a))


@wp.kernel
def element_hessian(x: wp.array(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i), dm_inv: wp.array(dtype=mat33d),
                    volume: wp.array(dtype=wp.float64), mu: wp.float64, lam: wp.float64, n_tets: int,
                    n_nodes: int, driven: wp.array(dtype=wp.int32), project: bool, blocks: wp.array(dtype=mat33d)):
    """The tet's 16 blocks K_ab = V sum_cd dP/dF[(r, c), (s, d)] g_a[c] g_b[d], zero where a or b is driven."""
    tid = wp.tid()
    world = tid // n_tets
    t = tid - world * n_tets
    tet = tets[t]
    F = deformation_gradient(x, tet, world * n_nodes, dm_inv[t])
    H = stress_derivative(F, mu, lam, project)
    for a in range(4):
        ga = shape_gradient(dm_inv[t], a)
        for b in range(4):
            K = wp.mat33d()
            if driven[tet[a]] == 0 and driven[tet[b]] == 0:
                gb = shape_gradient(dm_inv[t], b)
                for r in range(3):
                    for s in range(3):
                        k = wp.float64(0.0)
                        for c in range(3):
                            for d in range(3):
                                k += H[3 * r + c, 3 * s + d] * ga[c] * gb[d]
                        K[r, s] = volume[t] * k
            blocks[tid * 16 + 4 * a + b] = K


class ElasticEnergy:
    """The model's elastic energy over `worlds` copies of its mesh, evaluated at positions given as a (B N,) vec3d
    device array."""

    def __init__(self, model: FemModel, device: wp.context.Device, worlds: int):
        self.model, self.device, self.worlds = model, device, worlds
        rest, tets = model.rest_vertices, model.tets
        self.n_nodes, self.n_tets = len(rest), len(tets)
        edges = rest[tets[:, 1:]] - rest[tets[:, :1]]                 # (T, 3 edges, 3 coords)
        Dm = np.transpose(edges, (0, 2, 1))                           # columns are the edges
        self.mu, self.lam = model.settings.lame
        self.tets = wp.array(tets.astype(np.int32), dtype=wp.vec4i, device=device)
        self.dm_inv = wp.array(np.linalg.inv(Dm), dtype=mat33d, device=device)
        self.volume = wp.array(np.abs(np.linalg.det(Dm)) / 6.0, dtype=wp.float64, device=device)
        driven = np.zeros(self.n_nodes, dtype=np.int32)
        driven[model.driven] = 1
        self.driven = wp.array(driven, dtype=wp.int32, device=device)
        self.hessian, self._blocks, self._mapping = self._hessian_layout(tets, driven)

    def _args(self, x: wp.array) -> list:
        return [x, self.tets, self.dm_inv, self.volume, self.mu, self.lam, self.n_tets, self.n_nodes]

    def _hessian_layout(self, tets: np.ndarray, driven: np.ndarray):
        """The Hessian's sparsity (every pair of nodes sharing a tet, every world on the diagonal) built once, and
        the triplet values it is refilled from: the tets' 16 blocks each, then one diagonal block per node (the
        identity for a driven node, zero otherwise: a free node's diagonal comes from its tets)."""
        b, n, t = self.worlds, self.n_nodes, self.n_tets
        offsets = (np.arange(b) * n)[:, None, None]
        rows = (np.repeat(tets, 4, axis=1)[None] + offsets).ravel()   # (B, T, 16): a-major, like the kernel
        cols = (np.tile(tets, (1, 4))[None] + offsets).ravel()
        diagonal = np.arange(b * n)
        rows, cols = np.concatenate([rows, diagonal]), np.concatenate([cols, diagonal])
        values = np.zeros((b * t * 16 + b * n, 3, 3))
        values[b * t * 16:][np.tile(driven, b) == 1] = np.eye(3)
        hessian = wps.bsr_zeros(b * n, b * n, mat33d, device=self.device)
        as_array = lambda a, dtype: wp.array(a, dtype=dtype, device=self.device)  # noqa: E731
        blocks = as_array(values, mat33d)
        mapping = wps.bsr_set_from_triplets(hessian, as_array(rows.astype(np.int32), wp.int32),
                                            as_array(cols.astype(np.int32), wp.int32), blocks,
                                            prune_numerical_zeros=False, build_mapping=True)
        hessian.nnz_sync()
        return hessian, blocks, mapping

    def energy(self, x: wp.array, out: wp.array) -> None:
        """Each world's energy into `out` (B,) float64."""
        out.zero_()
        wp.launch(element_energy, dim=self.worlds * self.n_tets, inputs=[*self._args(x), out], device=self.device)

    def gradient(self, x: wp.array, out: wp.array) -> None:
        """dE/dx into `out` (B N,) vec3d, zero on the driven nodes."""
        out.zero_()
        wp.launch(element_gradient, dim=self.worlds * self.n_tets, inputs=[*self._args(x), self.driven, out],
                  device=self.device)

    def assemble_hessian(self, x: wp.array, project: bool = True) -> wps.BsrMatrix:
        """d2E/dx2 at x (with `project`, each tet's projected onto the positive semi-definite matrices), the driven
        nodes' rows and columns replaced by the identity's. The returned matrix is refilled by the next call."""
        wp.launch(element_hessian, dim=self.worlds * self.n_tets,
                  inputs=[*self._args(x), self.driven, project, self._blocks], device=self.device)
        wps.bsr_set_from_mapped_values(self.hessian, self._mapping, self._blocks)
        return self.hessian
