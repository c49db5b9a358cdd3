"""How a trained network's inference is timed, the same way wherever a figure is reported (the evaluate stage's
report and eval.h5, the tradeoff stage's table): one frame per call after warm-up runs, synchronised on CUDA, on
the deployment path (model.inference's fast path, replayed as one CUDA graph on a GPU) beside eager PyTorch and,
on CUDA, beside what a user deploys there: the fused bf16 network (model.fused_network)."""
from __future__ import annotations

import contextlib
import dataclasses
import importlib.util
import time
import warnings
from typing import Callable

import numpy as np
import torch

from model.features import FrameStore
from model.cuda_graph import CapturedCall
from model.inference import FUSED_FORMS, FastRegressor, captured_frames
from model.tasks import VectorStore
from pipeline.artifacts.evaluation import FusedTiming

WARMUP_RUNS = 3
FUSED_PATH = "model.fused_network (Triton), bf16 hidden layers, fp32 first and last convolutions"


def pick_frames(frames: np.ndarray, count: int) -> np.ndarray:
    """`count` of `frames` (sorted ids) spread evenly: the middle one of each of `count` equal parts (so one
    frame of a sequence is from its middle, not its first, still frame), or all of them."""
    n = min(max(count, 0), len(frames))
    return frames[((np.arange(n) + 0.5) * len(frames) / max(n, 1)).astype(np.int64)]


class InferenceTimes(np.ndarray):
    """ms of each timed frame on the deployment path (the array: eval.h5's inference_ms), carrying for the report
    the eager network's ms on the same frames (`eager`), the deployment path in words (`path`) and the fused bf16
    network's times (`fused`; None where it was not timed: on the CPU, where it does not run, and for a decoder)."""

    eager: np.ndarray
    path: str
    fused: FusedTiming | None


@contextlib.contextmanager
def _bf16_sums_in_fp32():
    """cuBLAS bf16 GEMMs with split-K partial sums in fp32 too (as bench/infer.py measures the fused path)."""
    matmul = torch.backends.cuda.matmul
    before = matmul.allow_bf16_reduced_precision_reduction
    matmul.allow_bf16_reduced_precision_reduction = False
    try:
        yield
    finally:
        matmul.allow_bf16_reduced_precision_reduction = before


def _deployed(fast: FastRegressor, store: FrameStore, ids: torch.Tensor, path: str) -> tuple[Callable, str]:
    """`fast` as deployed on the device of `ids`: one replayed CUDA graph on CUDA, launched where it cannot be
    captured (a feature's kernel), as is on the CPU; and its path in words."""
    if not ids.is_cuda:
        return fast, f"{path}, inference_mode"
    try:
        return captured_frames(fast, store.batch(ids[:1])), f"{path}, replayed as one CUDA graph"
    except RuntimeError as err:       # a feature's kernel that cannot be captured: time it launched
        return fast, f"{path}, launched kernel by kernel (no CUDA graph: {str(err).splitlines()[0]})"


def _relative(got: torch.Tensor, expected: torch.Tensor) -> float:
    return float((got - expected).abs().max() / expected.abs().max().clamp_min(1e-30))


def _per_frame(run: Callable, store, ids: torch.Tensor, grad_mode) -> tuple[np.ndarray, torch.Tensor]:
    """ms of `run(batch)` for each frame of `ids` alone (batch of one) after WARMUP_RUNS untimed calls,
    synchronised on CUDA, and the outputs (cloned: a replayed graph overwrites its own)."""
    sync = torch.cuda.synchronize if ids.is_cuda else (lambda: None)
    times, outputs = [], []
    with grad_mode():
        for i in range(-WARMUP_RUNS, len(ids)):
            batch = store.batch(ids[max(i, 0):max(i, 0) + 1])
            sync()
            start = time.perf_counter()
            output = run(batch)
            sync()
            if i >= 0:
                times.append((time.perf_counter() - start) * 1e3)
                outputs.append(output.clone())
    return np.asarray(times), torch.cat(outputs)


def time_inference(model, mesh, store: FrameStore, ids: torch.Tensor, fused: bool = True) -> InferenceTimes:
    """Milliseconds per frame (batch of one: its input features and the network, S x_low given) for each frame
    of `ids` after warm-up runs, synchronised on CUDA: on the deployment path (model.inference.FastRegressor,
    fp32, replayed as one CUDA graph on CUDA, under inference_mode with the configured threads on the CPU) and,
    on the same frames, eager PyTorch; on CUDA (with Triton), where `fused`, also the fused bf16 network
    (`FusedTiming`), replayed the same way: the faster of its FUSED_FORMS, as an export keeps (the other's median
    in its path)."""
    eager_ms, expected = _per_frame(lambda frame: model(frame, mesh), store, ids, torch.no_grad)
    deployed, path = _deployed(FastRegressor(model, mesh).to(ids.device), store, ids,
                               "model.inference fast path, fp32")
    deployed_ms, got = _per_frame(deployed, store, ids, torch.inference_mode)
    times = deployed_ms.view(InferenceTimes)
    times.eager, times.path = eager_ms, f"{path}; within {_relative(got, expected):.0e} of the eager output"
    times.fused = None
    if ids.is_cuda and not fused:
        times.path += "; the fused bf16 network not timed (not asked for)"
    elif ids.is_cuda and importlib.util.find_spec("triton") is not None:    # PyTorch's CUDA builds bring Triton
        # An extra figure beside the fp32 path's: a network the fused kernels cannot run (or a Triton that cannot
        # compile them) leaves it out with its reason rather than failing the stage that asked for the times.
        forms, failures = {}, []
        for name, options in FUSED_FORMS.items():
            try:
                forms[name] = _time_fused(model, mesh, store, ids, got, name, options)
            except Exception as err:     # noqa: BLE001 -- Triton's compile errors derive from no common base
                reason = str(err).splitlines()[0] if str(err) else type(err).__name__
                failures.append(f"{name}: {reason}")
        times.fused = fastest_fused(forms, failures)
        if times.fused is None:
            times.path += f"; the fused bf16 network not timed ({'; '.join(failures)})"
            warnings.warn(f"the fused bf16 network was not timed: {'; '.join(failures)}", RuntimeWarning,
                          stacklevel=2)
    return times


def fastest_fused(forms: dict[str, FusedTiming], failures: list[str]) -> FusedTiming | None:
    """The timing of the form with the least median ms, its path naming the others' medians and the forms that
    failed ("form: reason"); None where none was timed."""
    if not forms:
        return None
    fastest = min(forms, key=lambda name: np.median(forms[name].ms))
    others = [f"{name} {np.median(timing.ms):.3f} ms" for name, timing in forms.items() if name != fastest]
    others += [f"{failure} (not timed)" for failure in failures]
    chosen = forms[fastest]
    return dataclasses.replace(chosen, path=chosen.path + (
        f"; the faster form (median), beside {', '.join(others)}" if others else ""))


def _time_fused(model, mesh, store: FrameStore, ids: torch.Tensor, fp32_out: torch.Tensor, form: str,
                options: dict) -> FusedTiming:
    """The fused bf16 network in one of FUSED_FORMS, timed as time_inference times the fp32 path, and its error
    against that path's outputs."""
    with _bf16_sums_in_fp32():
        regressor = FastRegressor(model, mesh, torch.bfloat16, fused=True, **options).to(ids.device)
        features = ("input features in PyTorch (model.features)" if regressor.fused_features is None
                    else "input features in one kernel (model.fused_features)")
        kernels = "one persistent kernel for the network" if options.get("persistent") else "kernels by level"
        fused, fused_path = _deployed(regressor, store, ids, f"{FUSED_PATH} ({form}: {kernels}), {features}")
        fused_ms, fused_out = _per_frame(fused, store, ids, torch.inference_mode)
    return FusedTiming(fused_ms, _relative(fused_out, fp32_out), fused_path)


def time_decoder(model, mesh, store: VectorStore, ids: torch.Tensor) -> InferenceTimes:
    """time_inference for a decoder task (model.inference's fast path covers the encoder-decoder only, and so
    does the fused network: `fused` is None): the network, its input vector given, batch of one, after warm-up
    runs, synchronised on CUDA - eager PyTorch under inference_mode and, on CUDA, that network replayed as one
    CUDA graph (its deployment path there: a decoder of ~100 small launches is bound by launching them)."""
    eager_ms, expected = _per_frame(lambda batch: model(batch, mesh), store, ids, torch.inference_mode)
    measured, path = eager_ms.view(InferenceTimes), "eager PyTorch, fp32, inference_mode"
    if ids.is_cuda:
        try:
            example = store.batch(ids[:1])
            captured = CapturedCall(lambda values: model(dataclasses.replace(example, values=values), mesh),
                                    example.values)
            graph_ms, got = _per_frame(lambda batch: captured(batch.values), store, ids, torch.inference_mode)
            measured = graph_ms.view(InferenceTimes)
            path = (f"eager PyTorch fp32 replayed as one CUDA graph; within {_relative(got, expected):.0e} of the "
                    f"eager output")
        except RuntimeError as err:   # an operation that cannot be captured: the eager figure is the deployed one
            path += f" (no CUDA graph: {str(err).splitlines()[0]})"
    measured.eager, measured.path, measured.fused = eager_ms, path, None
    return measured
