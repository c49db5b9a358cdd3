"""Networks on the fixture mesh: shapes, finite-difference gradients, mesh checks, and overfitting a few frames."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from model_meshes import build_hierarchy, grid_mesh
from model.losses import l1_loss
from model.networks import NetworkSpec, build_network


def test_encoder_decoder_shapes_and_levels(grid):
    _, _, mesh = grid
    net = build_network(NetworkSpec("D8 D16 D D16", "RC7", "max"))
    assert net.n_levels == 4
    out = net(torch.randn(2, mesh.vertex_counts[0], 3), mesh)
    assert out.shape == (2, mesh.vertex_counts[0], 3)
    assert torch.isfinite(out).all()


def test_encoder_decoder_gradient_matches_finite_differences(grid):
    _, _, mesh = grid
    net = build_network(NetworkSpec("D4 D D6", "RC7")).double()
    x = torch.randn(1, mesh.vertex_counts[0], 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: net(x, mesh), (x,), atol=1e-6)
    weight = net.convs[1].weight                        # a weight deep inside: the gradient reaches it
    probe = lambda w: torch.func.functional_call(net, {"convs.1.weight": w}, (x.detach(), mesh))  # noqa: E731
    assert torch.autograd.gradcheck(probe, (weight.detach().clone().requires_grad_(),), atol=1e-6)


def test_every_level_and_skip_influences_the_output(grid):
    """Zeroing the bottleneck conv or a skip changes the output: the whole wiring is live."""
    _, _, mesh = grid
    net = build_network(NetworkSpec("D4 D D6", "RC7"))
    x = torch.randn(1, mesh.vertex_counts[0], 3)
    reference = net(x, mesh).detach()
    for index in range(len(net.convs) - 1):
        with torch.no_grad():
            saved = net.convs[index].weight.clone()
            net.convs[index].weight.zero_()
            assert not torch.allclose(net(x, mesh), reference), f"conv {index} has no effect"
            net.convs[index].weight.copy_(saved)


def test_network_rejects_too_shallow_or_wrong_size_mesh(grid):
    _, _, mesh = grid
    with pytest.raises(ValueError, match="needs 7 mesh levels .* provide 5"):
        build_network(NetworkSpec("D4 D D D D D D6", "RC7")).check_mesh(mesh)
    with pytest.raises(ValueError, match="size 13"):
        build_network(NetworkSpec("D4", "RC13")).check_mesh(mesh)


def test_encoder_decoder_is_fully_convolutional(grid):
    _, _, mesh = grid
    vertices, faces = grid_mesh(9, 5)
    other = build_hierarchy(faces, len(vertices), 7, 5)
    net = build_network(NetworkSpec("D8 D D8", "RC7"))
    assert net(torch.randn(1, 45, 3), other).shape == (1, 45, 3)
    assert net(torch.randn(1, mesh.vertex_counts[0], 3), mesh).shape == (1, mesh.vertex_counts[0], 3)


def test_decoder_shapes_and_parameter_count(grid):
    _, _, mesh = grid
    coarse = mesh.vertex_counts[3]
    net = build_network(NetworkSpec("U8 U U3", "RC7", in_channels=5, coarse_vertices=coarse))
    net.check_mesh(mesh)
    out = net(torch.randn(2, 5), mesh)
    assert out.shape == (2, mesh.vertex_counts[0], 3)
    fully_connected = 5 * coarse * 8 + coarse * 8
    convs = [(8, 8), (8, 8), (8, 3), (3, 3)]
    assert net.parameter_count() == fully_connected + sum(7 * a * b + b for a, b in convs)
    with pytest.raises(ValueError, match="coarsest level"):
        build_network(NetworkSpec("U8 U U3", "RC7", in_channels=5, coarse_vertices=coarse + 1)).check_mesh(mesh)


def _patch_frames(vertices: np.ndarray, n_frames: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Smooth waving inputs and a finer, input-dependent displacement to learn."""
    inputs, targets = [], []
    for t in range(n_frames):
        p = vertices.copy()
        p[:, 1] = 0.1 * np.sin(3 * vertices[:, 0] + t) * vertices[:, 2]
        inputs.append(p)
        targets.append(0.01 * np.stack([np.sin(9 * p[:, 0] + 5 * p[:, 1]), np.cos(7 * p[:, 2]),
                                        np.sin(11 * p[:, 0] * p[:, 2] + t)], axis=1))
    return torch.tensor(np.array(inputs), dtype=torch.float32), torch.tensor(np.array(targets), dtype=torch.float32)


def test_network_overfits_a_handful_of_frames(grid):
    vertices, _, mesh = grid
    torch.set_flush_denormal(True)
    x, y = _patch_frames(vertices, 4)
    mesh_net = build_network(NetworkSpec("D16 D32 D D32", "RC7"))
    net = lambda inputs, mesh: mesh_net((inputs - x.mean(dim=(0, 1))) / x.std(), mesh) * y.std()   # noqa: E731
    optimizer = torch.optim.Adam(mesh_net.parameters(), lr=1e-3, betas=(0.9, 0.999), eps=1e-8)
    losses = []
    for _ in range(300):
        loss = l1_loss(net(x, mesh), y)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0] / 10, f"L1 went from {losses[0]:.3g} to {losses[-1]:.3g}"


@pytest.mark.parametrize("inputs, coarse, expected", [
    (208, 48, 7_117_519),    # dress2, pose -> cloth (paper Table 4, RC13)
    (208, 36, 6_595_855),    # tank-male
    (32, 53, 5_394_655),     # cape, PCA 32
    (64, 53, 5_747_423),     # cape, PCA 64
])
def test_the_papers_decoder_has_table_4s_parameter_counts(inputs, coarse, expected):
    """U208 U U208 U U208 U U208 U104 U52 U3 with RC13: the fully connected layer (inputs + 1) x 208 per
    coarsest-level vertex, then the same convolutions whatever the mesh; Table 4's four counts pin both parts."""
    spec = NetworkSpec("U208 U U208 U U208 U U208 U104 U52 U3", "RC13", in_channels=inputs, coarse_vertices=coarse)
    assert build_network(spec).parameter_count() == expected
