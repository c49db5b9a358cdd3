"""pipeline.tasks.timing's contract beside the fp32 deployment path: the fused bf16 network (model.fused_network)
is timed on CUDA only, on the same frames, with its error against the fp32 path; on the CPU it is absent (None in
the times, no dataset in eval.h5, NaN in the trade-off's columns) and the fp32 figures are what they were. The
CUDA test is skipped without CUDA and Triton."""
from __future__ import annotations

import importlib.util

import h5py
import numpy as np
import pytest
import torch
from stage_inputs import grid

from meshops import build_operators
from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.features import FrameBatch
from model.mesh_hierarchy import mesh_hierarchy
from model.networks import NetworkSpec, build_network
from model.tasks import VectorRegressor, VectorSpec, VectorStore
from pipeline.artifacts.evaluation import Evaluation, FusedTiming, read_network_timing, write_evaluation
from pipeline.core.errors import PipelineError
from pipeline.tasks.timing import fastest_fused, time_decoder, time_inference

# bf16 hidden layers against fp32: 0.3-1 % of the largest displacement (model/inference.py; bench/infer.py's
# error column), twice that allowed.
FUSED_TOLERANCE = 2e-2


class _Frames:
    """A store of frames (positions only, the paper's input) answering `batch(ids)` as model.features' does."""

    def __init__(self, positions: torch.Tensor):
        self.positions = positions

    def batch(self, ids: torch.Tensor) -> FrameBatch:
        return FrameBatch(self.positions[ids], None, None, None, None, None, None, None, 0.1)


ERRORS = {who: {"test": {"l1": 1.0, "l2": 1.0}} for who in ("network", "predictor")}


def _network(device: str):
    torch.manual_seed(0)
    vertices, faces = grid(12)
    levels = build_operators(vertices, faces, conv=["RC9"], pooling_steps=4)
    mesh = mesh_hierarchy([lv.conv["RC9"] for lv in levels], [lv.coarsening.pool for lv in levels[:-1]],
                          [lv.coarsening.unpool for lv in levels[:-1]]).to(device)
    spec = FeatureSpec()
    net = build_network(NetworkSpec("D16 D32 D D32", "RC9", "max", in_channels=spec.channels))
    model = FeatureRegressor(net, spec, faces, vertices, 0.1 * torch.randn(spec.channels),
                             torch.rand(spec.channels) + 0.5, 0.01).eval().to(device)
    rest = torch.as_tensor(vertices, dtype=torch.float32)
    frames = _Frames((rest + 0.05 * torch.randn(6, *rest.shape)).to(device))
    return model, mesh, frames, torch.arange(4, device=device)


def test_on_the_cpu_the_fused_network_is_not_timed_and_eval_h5_holds_no_fused_times(tmp_path):
    model, mesh, frames, ids = _network("cpu")
    times = time_inference(model, mesh, frames, ids)
    assert times.fused is None and times.shape == (4,) and np.all(times > 0)
    assert times.path.startswith("model.inference fast path, fp32, inference_mode")
    assert time_decoder(model, mesh, frames, ids).fused is None
    evaluation = Evaluation(ERRORS, {}, None, np.asarray(times), np.arange(4), "cpu", 3, 10, 5, fused=times.fused)
    write_evaluation(tmp_path / "eval.h5", {"model_spec": {"conv": "RC9", "width": 1.0}}, evaluation)
    with h5py.File(tmp_path / "eval.h5") as f:
        assert "inference_ms_fused" not in f
    assert read_network_timing(tmp_path / "eval.h5").fused is None


def test_fused_times_round_trip_through_eval_h5_and_bad_ones_are_refused(tmp_path):
    config = {"model_spec": {"conv": "RC9", "width": 1.0}}
    fused = FusedTiming(np.array([0.4, 0.5]), 3e-3, "fused, replayed as one CUDA graph")
    write_evaluation(tmp_path / "eval.h5", config,
                     Evaluation(ERRORS, {}, None, np.array([3.0, 3.2]), np.arange(2), "H100", 3, 10, 5, fused=fused))
    back = read_network_timing(tmp_path / "eval.h5").fused
    np.testing.assert_array_equal(back.ms, fused.ms)
    assert (back.error, back.path) == (fused.error, fused.path)
    with h5py.File(tmp_path / "eval.h5", "r+") as f:
        del f["inference_ms_fused"]
        f["inference_ms_fused"] = np.array([0.4])         # not one per timed frame
    with pytest.raises(PipelineError, match="inference_ms_fused"):
        read_network_timing(tmp_path / "eval.h5")


def test_the_faster_fused_form_is_reported_with_the_others():
    separate = FusedTiming(np.array([0.20, 0.22, 0.21]), 2e-3, "separate")
    persistent = FusedTiming(np.array([0.15, 0.30, 0.14]), 3e-3, "persistent")   # the lower median, not mean
    chosen = fastest_fused({"separate": separate, "persistent": persistent}, [])
    assert chosen.error == 3e-3 and chosen.path == "persistent; the faster form (median), beside separate 0.210 ms"
    chosen = fastest_fused({"separate": separate}, ["persistent: out of shared memory"])
    assert chosen.path == "separate; the faster form (median), beside persistent: out of shared memory (not timed)"
    assert fastest_fused({"separate": separate}, []) == separate
    assert fastest_fused({}, ["separate: no Triton"]) is None


@pytest.mark.skipif(not torch.cuda.is_available() or importlib.util.find_spec("triton") is None,
                    reason="the fused network runs on CUDA with Triton")
def test_on_cuda_the_fused_network_is_timed_on_the_same_frames_within_bf16_of_fp32():
    model, mesh, frames, ids = _network("cuda")
    times = time_inference(model, mesh, frames, ids)
    print(f"fp32 {np.median(times):.3f} ms, fused bf16 {np.median(times.fused.ms):.3f} ms, error "
          f"{times.fused.error:.1e}; {times.fused.path}")
    assert times.fused.ms.shape == times.shape and np.all(np.isfinite(times.fused.ms) & (times.fused.ms > 0))
    assert 0 < times.fused.error < FUSED_TOLERANCE
    assert "CUDA graph" in times.fused.path and "the faster form (median), beside" in times.fused.path
    alone = time_inference(model, mesh, frames, ids, fused=False)     # what the grids' evaluations ask for
    assert alone.fused is None and alone.path.endswith("the fused bf16 network not timed (not asked for)")


def _decoder(device: str):
    """A decoder of three unpoolings from 5 scalars onto the 12 x 12 grid, its store of 6 frames and 4 timed ids."""
    torch.manual_seed(0)
    vertices, faces = grid(12)
    levels = build_operators(vertices, faces, conv=["RC9"], pooling_steps=3)
    mesh = mesh_hierarchy([lv.conv["RC9"] for lv in levels], [lv.coarsening.pool for lv in levels[:-1]],
                          [lv.coarsening.unpool for lv in levels[:-1]])
    net = build_network(NetworkSpec("U8 U U3", "RC9", in_channels=5, coarse_vertices=mesh.vertex_counts[-1]))
    model = VectorRegressor(net, VectorSpec(("pose",)), torch.randn(5), torch.rand(5) + 0.5, 0.01).eval()
    store = VectorStore(torch.zeros(6, len(vertices), 3), torch.randn(6, 5))
    move = lambda x: x.to(device)  # noqa: E731
    return model.to(device), mesh.to(device), VectorStore(move(store.positions), move(store.values)), \
        torch.arange(4, device=device)


def test_a_decoder_is_timed_eager_on_the_cpu_on_the_frames_asked():
    model, mesh, store, ids = _decoder("cpu")
    times = time_decoder(model, mesh, store, ids)
    assert times.shape == (4,) and np.all(times > 0) and times.fused is None
    assert times.path == "eager PyTorch, fp32, inference_mode" and np.array_equal(times, times.eager)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a CUDA device")
def test_on_cuda_a_decoder_is_timed_as_one_replayed_graph_giving_the_eager_output():
    model, mesh, store, ids = _decoder("cuda")
    times = time_decoder(model, mesh, store, ids)
    print(f"decoder: graph {np.median(times):.3f} ms, eager {np.median(times.eager):.3f} ms; {times.path}")
    assert times.shape == times.eager.shape == (4,) and np.all(times > 0) and times.fused is None
    assert times.path.startswith("eager PyTorch fp32 replayed as one CUDA graph; within ")
    assert float(times.path.split("within ")[1].split(" ")[0]) < 1e-5
