"""Layers against explicit loops, finite differences and torch's own reference implementations."""
from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from model.mesh_hierarchy import mesh_hierarchy
from model.layers import MeshConv, avg_pool, instance_norm, max_pool, mesh_conv, unpool


def test_conv_equals_per_vertex_loop(grid):
    _, _, mesh = grid
    table = mesh.conv[0]
    n_vertices, size = table.shape
    conv = MeshConv(4, 5, size).double()
    x = torch.randn(2, n_vertices, 4, dtype=torch.float64)
    out = conv(x, table)
    weight = conv.weight.detach().reshape(size, 4, 5).numpy()
    expected = np.zeros((2, n_vertices, 5))
    for b in range(2):
        for v in range(n_vertices):
            expected[b, v] = conv.bias.detach().numpy()
            for slot, vid in enumerate(table[v].tolist()):
                if vid > 0:                       # 0 is the zero-padding slot
                    expected[b, v] += x[b, vid - 1].numpy() @ weight[slot]
    assert out.shape == (2, n_vertices, 5)
    np.testing.assert_allclose(out.detach().numpy(), expected, rtol=1e-12, atol=1e-12)
    assert (table == 0).any(), "the fixture must exercise padding"


def test_conv_rejects_table_of_other_size(grid):
    _, _, mesh = grid
    with pytest.raises(ValueError, match="L=9"):
        MeshConv(3, 3, 9)(torch.zeros(1, mesh.vertex_counts[0], 3), mesh.conv[0])


def test_gradients_match_finite_differences(grid):
    _, _, mesh = grid
    table, pool_table, unpool_table = mesh.conv[1], mesh.pool[0], mesh.unpool[0]
    n_fine, n_coarse = mesh.vertex_counts[0], mesh.vertex_counts[1]
    double = dict(dtype=torch.float64, requires_grad=True)
    x = torch.randn(2, n_coarse, 3, **double)
    w = torch.randn(table.shape[1] * 3, 2, **double)
    b = torch.randn(2, **double)
    assert torch.autograd.gradcheck(lambda x, w, b: mesh_conv(x, table, w, b), (x, w, b))
    fine = torch.randn(2, n_fine, 3, **double)     # distinct values: max pooling is differentiable there
    assert torch.autograd.gradcheck(lambda x: avg_pool(x, pool_table), (fine,))
    assert torch.autograd.gradcheck(lambda x: max_pool(x, pool_table), (fine,))
    assert torch.autograd.gradcheck(lambda x: unpool(x, unpool_table), (x,))
    assert torch.autograd.gradcheck(lambda x: instance_norm(x), (x,))


def test_unpool_then_pool_is_identity_and_max_picks_the_max(grid):
    _, _, mesh = grid
    for level in range(len(mesh.pool)):
        pool_table, unpool_table = mesh.pool[level], mesh.unpool[level]
        coarse = torch.randn(3, mesh.vertex_counts[level + 1], 4)
        for pool in (avg_pool, max_pool):
            torch.testing.assert_close(pool(unpool(coarse, unpool_table), pool_table), coarse)
        fine = torch.randn(3, mesh.vertex_counts[level], 4)
        merged = [np.flatnonzero(unpool_table.numpy() == c) for c in range(mesh.vertex_counts[level + 1])]
        expected_max = np.stack([fine.numpy()[:, m].max(axis=1) for m in merged], axis=1)
        expected_avg = np.stack([fine.numpy()[:, m].mean(axis=1) for m in merged], axis=1)
        np.testing.assert_allclose(max_pool(fine, pool_table).numpy(), expected_max, rtol=1e-6)
        np.testing.assert_allclose(avg_pool(fine, pool_table).numpy(), expected_avg, rtol=1e-6)
        assert max(len(m) for m in merged) == 2 and min(len(m) for m in merged) >= 1


def test_instance_norm_matches_torch():
    x = torch.randn(2, 50, 6) * 3 + 1
    expected = F.instance_norm(x.transpose(1, 2), eps=1e-5).transpose(1, 2)
    torch.testing.assert_close(instance_norm(x), expected)
    y = instance_norm(x)
    torch.testing.assert_close(y.mean(dim=1), torch.zeros(2, 6), atol=1e-5, rtol=0)
    torch.testing.assert_close(y.var(dim=1, unbiased=False), torch.ones(2, 6), atol=1e-3, rtol=0)
    assert torch.isfinite(instance_norm(torch.ones(1, 5, 2))).all()      # constant features: eps keeps it finite


@pytest.mark.parametrize("break_it, message", [
    (lambda c, p, u: c[0].__setitem__((0, 0), 2), "column 0"),
    (lambda c, p, u: c[1].__setitem__((0, 1), 10_000), "must lie in"),
    (lambda c, p, u: u[0].__setitem__(p[0][0, 0], (u[0][p[0][0, 0]] + 1) % len(p[0])), "disagree"),
    (lambda c, p, u: p.pop(), "pool and unpool tables"),
])
def test_hierarchy_rejects_bad_tables(grid, break_it, message):
    _, _, mesh = grid
    conv = [t.numpy().copy() for t in mesh.conv]
    pool = [t.numpy().copy() for t in mesh.pool]
    unpool_tables = [t.numpy().copy() for t in mesh.unpool]
    mesh_hierarchy(conv, pool, unpool_tables)
    break_it(conv, pool, unpool_tables)
    with pytest.raises(ValueError, match=message):
        mesh_hierarchy(conv, pool, unpool_tables)


def test_fingerprint_tells_hierarchies_apart(grid):
    _, _, mesh = grid
    changed = [t.numpy().copy() for t in mesh.conv]
    changed[0][0, 1:] = np.roll(changed[0][0, 1:], 1)
    other = mesh_hierarchy(changed, [t.numpy() for t in mesh.pool], [t.numpy() for t in mesh.unpool])
    assert mesh.fingerprint() == mesh_hierarchy([t.numpy() for t in mesh.conv], [t.numpy() for t in mesh.pool],
                                                [t.numpy() for t in mesh.unpool]).fingerprint()
    assert other.fingerprint() != mesh.fingerprint()
