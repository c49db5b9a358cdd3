"""The fused features (one Triton kernel: model.triton_features) against model.features' PyTorch path.

Its tables are checked on every machine: the corner table's cross products sum to model.features' vertex normals,
the neighbour table's mean is the umbrella Laplacian's. The kernel is checked against InputFeatures.with_frames
(features and frames) for every covered feature, both frames of reference and both tangents, on capsules placed so
that vertices fall in each of the three nearest-surface cases and inside: on CUDA, and on the CPU through Triton's
interpreter where Triton is installed (not a CPU requirement: this file then runs itself in a subprocess with
TRITON_INTERPRET=1, set before Triton is imported). Where the kernel runs, the whole fast regressor with the fused
network and features is checked against the eager model too."""
from __future__ import annotations

import dataclasses
import importlib.util
import json
import os

import numpy as np
import pytest
import torch

from model.feature_regressor import FeatureRegressor
from model.feature_spec import FeatureSpec
from model.features import FrameBatch, InputFeatures, umbrella_laplacian, vertex_normals
from model.fused_features import COVERED, FusedFeatures, corner_table, neighbour_table, padded_rows
from model.inference import FastRegressor
from model.networks import NetworkSpec, build_network
from model_meshes import build_hierarchy, grid_mesh
from triton_interpreted import interpreted_errors

TOLERANCE = 1e-5       # of each feature's largest |value|: summation order and division forms, nothing else
SPECS = {
    "body_relative": FeatureSpec(("velocity", "body", "laplacian", "gravity"), "local", "local", "gravity"),
    "every_covered": FeatureSpec(COVERED, "dataset", "dataset", "edge"),
    "local_edge": FeatureSpec(("position", "acceleration", "rest_position", "body"), "local", "local", "edge"),
    "dataset_in_local_out": FeatureSpec(("laplacian", "velocity", "body"), "dataset", "local", "gravity"),
}


def _mesh() -> tuple[np.ndarray, np.ndarray]:
    """A wavy 9 x 11 grid: 99 vertices, interior valence 6, boundary and corner vertices with fewer faces."""
    vertices, faces = grid_mesh(9, 11)
    vertices = vertices.astype(np.float32)
    vertices[:, 1] += 0.1 * np.sin(3.0 * vertices[:, 0]) * np.cos(2.0 * vertices[:, 2])
    return vertices, faces


def _frames(vertices: np.ndarray, batch: int = 2) -> FrameBatch:
    """Moved copies of the mesh with capsules through it: one long (vertices nearest its side), one tapered and
    short beside the grid (nearest its ends), one small sphere-like one (vertices inside it)."""
    generator = torch.Generator().manual_seed(3)
    rest = torch.as_tensor(vertices)
    noise = lambda size: size * torch.randn(batch, *rest.shape, generator=generator)  # noqa: E731
    positions = rest + noise(0.02)
    previous = positions + noise(0.01)
    centre = rest.mean(dim=0)
    a = torch.stack([centre + torch.tensor([-0.4, 0.0, 0.2]), centre + torch.tensor([0.8, 0.9, -0.1]),
                     centre + torch.tensor([0.05, 0.05, 0.0])])
    b = torch.stack([centre + torch.tensor([0.4, 0.1, 0.2]), centre + torch.tensor([0.9, 1.2, 0.1]),
                     centre + torch.tensor([0.06, 0.05, 0.01])])
    shift = torch.tensor([[0.0, 0.0, 0.0], [0.03, -0.02, 0.01]])[:batch, None]
    gravity = torch.nn.functional.normalize(torch.tensor([[0.3, -1.0, 0.2], [0.0, 0.0, -1.0]])[:batch], dim=-1)
    return FrameBatch(positions, previous, previous + noise(0.01), a + shift, b + shift,
                      torch.tensor([0.15, 0.2, 0.1]), torch.tensor([0.15, 0.05, 0.1]), gravity, 1.0 / 30.0)


def _on(frames: FrameBatch, device: str) -> FrameBatch:
    return dataclasses.replace(frames, **{field.name: getattr(frames, field.name).to(device)
                                          for field in dataclasses.fields(frames)
                                          if isinstance(getattr(frames, field.name), torch.Tensor)})


def _feature_errors(device: str) -> dict[str, float]:
    """Per spec and feature (and the frames), the kernel's largest error relative to that feature's largest
    |value| on the PyTorch path."""
    vertices, faces = _mesh()
    frames = _frames(vertices)
    moved = _on(frames, device)
    errors = {}
    for name, spec in SPECS.items():
        want = spec.output_frame == "local"
        expected, expected_frames = InputFeatures.of(spec, faces, vertices).with_frames(frames, want)
        got, got_frames = FusedFeatures(spec, faces, vertices).to(device).with_frames(moved, want)
        start = 0
        for feature, width in zip(spec.inputs, InputFeatures.of(spec, faces, vertices).groups()):
            part = slice(start, start + width)
            errors[f"{name} {feature}"] = _relative(got[..., part].cpu(), expected[..., part])
            start += width
        if want:
            errors[f"{name} frames"] = _relative(got_frames.cpu(), expected_frames)
    return errors


def _regressor_errors(device: str) -> dict[str, float]:
    """The fast regressor with the fused network and features (fp32) against the eager model, per spec."""
    vertices, faces = grid_mesh(6, 7)
    mesh = build_hierarchy(faces, len(vertices), 7, 5)
    frames = _frames(vertices.astype(np.float32))
    errors = {}
    for name, spec in SPECS.items():
        net = build_network(NetworkSpec("D8 D16 D D16", "RC7", "max", in_channels=spec.channels))
        offset, scale = torch.randn(spec.channels), torch.rand(spec.channels) + 0.5
        model = FeatureRegressor(net, spec, faces, vertices, offset, scale, 0.3).eval()
        fast = FastRegressor(model, mesh, fused=True).to(device)
        assert fast.fused_features is not None
        with torch.no_grad():
            expected = model(frames, mesh)
            errors[name] = _relative(fast(_on(frames, device)).cpu(), expected)
    return errors


def _relative(got: torch.Tensor, expected: torch.Tensor) -> float:
    return float((got - expected).abs().max() / expected.abs().max().clamp_min(1e-30))


def test_padded_rows_keep_each_owners_values_in_order():
    table = padded_rows(np.array([2, 0, 2, 2]), np.array([7, 8, 9, 6]), 4)
    assert table.tolist() == [[8, -1, -1], [-1, -1, -1], [7, 9, 6], [-1, -1, -1]]


def test_tables_give_model_features_normals_and_laplacian():
    vertices, faces = _mesh()
    x = _frames(vertices).positions
    corners = torch.as_tensor(corner_table(faces, len(vertices))).long()
    real = (corners[..., 0] >= 0)[None, ..., None]
    first, second = (x[:, corners[..., k].clamp_min(0)] - x[:, :, None] for k in (0, 1))
    summed = torch.where(real, torch.linalg.cross(first, second, dim=-1), 0.0).sum(dim=2)
    torch.testing.assert_close(summed / summed.norm(dim=-1, keepdim=True), vertex_normals(x, torch.as_tensor(faces)),
                               rtol=1e-5, atol=1e-6)
    assert int(real.sum()) == 3 * len(faces)
    neighbours = torch.as_tensor(neighbour_table(faces, len(vertices))).long()
    valence = (neighbours >= 0).sum(dim=1)
    mean = torch.where((neighbours >= 0)[None, ..., None], x[:, neighbours.clamp_min(0)], 0.0).sum(dim=2)
    features = InputFeatures(("laplacian",), faces, vertices)
    torch.testing.assert_close(mean / valence[:, None] - x, umbrella_laplacian(x, features.edges, features.valence),
                               rtol=1e-5, atol=1e-6)
    assert valence.tolist() == features.valence.long().tolist()


def test_fused_features_cover_per_vertex_features_only():
    vertices, faces = _mesh()
    assert FusedFeatures.covers(SPECS["body_relative"])
    for uncovered in ("strain", "centered_position", "previous_output"):
        spec = FeatureSpec(("position", uncovered))
        assert not FusedFeatures.covers(spec)
        with pytest.raises(ValueError, match="the fused features compute"):
            FusedFeatures(spec, faces, vertices)
    fused = FusedFeatures(SPECS["every_covered"], faces, vertices)
    assert fused.layout == [0, 3, 6, 9, 12, 15, 18, 22, 25]
    if os.environ.get("TRITON_INTERPRET") != "1":
        with pytest.raises(ValueError, match="run on CUDA"):
            fused.with_frames(_frames(vertices), False)


def _check(errors: dict[str, float]) -> None:
    print(errors)
    expected = sum(len(spec.inputs) + (spec.output_frame == "local") for spec in SPECS.values())
    assert len(errors) == expected + len(SPECS) and max(errors.values()) < TOLERANCE


@pytest.mark.skipif(importlib.util.find_spec("triton") is None or torch.cuda.is_available(),
                    reason="needs Triton; where CUDA is, the test below runs the compiled kernel instead")
def test_kernel_interpreted_on_the_cpu_matches_the_pytorch_features():
    _check(interpreted_errors(__file__))


@pytest.mark.skipif(importlib.util.find_spec("triton") is None, reason="needs Triton")
@pytest.mark.parametrize("spec", SPECS.values(), ids=SPECS.keys())
def test_kernel_compiles_for_a_hopper_gpu_without_one(spec):
    """Triton's compiler for sm_90 on any machine: what the interpreter lets through (a loop variable that
    changes type, a constexpr used as a value) fails here, before a GPU lease is spent on it."""
    from triton import compile as compile_kernel
    from triton.backends.compiler import GPUTarget
    from triton.compiler import ASTSource

    from model.triton_features import BLOCK, _features_kernel

    vertices, faces = _mesh()
    fused = FusedFeatures(spec, faces, vertices)
    layout = dict(zip(("POSITION", "REST", "NORMAL", "LAPLACIAN", "VELOCITY", "ACCELERATION", "BODY", "GRAVITY",
                       "C"), fused.layout))
    want = spec.output_frame == "local"
    constants = {**layout, "F": fused.corners.shape[1], "N": fused.neighbours.shape[1], "LOCAL": fused.local_inputs,
                 "FRAMES": want, "NEED_FRAMES": fused.local_inputs or want, "GRAVITY_TANGENT": fused.gravity_tangent,
                 "BLOCK_V": BLOCK}
    integers = {"corners_ptr": "*i32", "neighbours_ptr": "*i32", "reference_ptr": "*i32", "n_vertices": "i32",
                "n_capsules": "i32"}
    signature = {name: "constexpr" if name in constants else integers.get(name, "*fp32")
                 for name in _features_kernel.arg_names}
    kernel = compile_kernel(ASTSource(_features_kernel, signature, constexprs=constants),
                            target=GPUTarget("cuda", 90, 32), options={"num_warps": 4})
    assert ".entry _features_kernel" in kernel.asm["ptx"]


@pytest.mark.skipif(not torch.cuda.is_available() or importlib.util.find_spec("triton") is None,
                    reason="needs CUDA and Triton")
def test_kernel_on_cuda_matches_the_pytorch_features():
    _check({**_feature_errors("cuda"), **{f"regressor {k}": v for k, v in _regressor_errors("cuda").items()}})


if __name__ == "__main__":      # the interpreted run of test_kernel_interpreted_on_the_cpu_matches_...
    print(json.dumps({**_feature_errors("cpu"), **{f"regressor {k}": v for k, v in _regressor_errors("cpu").items()}}))
