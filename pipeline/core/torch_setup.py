"""Torch as the learning stages (train, evaluate) use it: deterministic and seeded on one device (a task moves a
dataset's frames onto it: pipeline.tasks)."""
from __future__ import annotations

import os
import sys

import torch

from pipeline.core import gpu_slots
from pipeline.core.cli import check_device
from pipeline.core.errors import PipelineError


def configure_torch(device: str, seed: int, threads: int | None = None, *, deterministic: bool = True,
                    tf32: bool = False, cuda_graph: bool = False, whole_gpu: bool = False) -> torch.device:
    """Seeded torch on `device` using `threads` CPU threads (default: torch's choice), its arithmetic as
    `set_arithmetic` describes; fails clearly for a device that is no device (`gpu7`), a CUDA device torch does
    not see, or a device that is not CUDA for a training replayed as CUDA graphs (`cuda_graph`). `whole_gpu`: a
    GPU of the workflow's shared pool taken whole (pipeline.core.gpu_slots), for times that no other job's
    kernels share."""
    if threads is not None:
        if threads < 1:
            raise PipelineError(f"--threads must be >= 1, got {threads}")
        torch.set_num_threads(threads)
    check_device(device, "torch", torch.cuda.device_count, whole_gpu)
    if cuda_graph and not device.startswith("cuda"):
        raise PipelineError(f"--cuda-graph (training.cuda_graph) needs a CUDA device, not '{device}'")
    if device.startswith("cuda"):
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")   # deterministic cuBLAS
    set_arithmetic(deterministic, tf32)
    # Deterministic mode also fills every new tensor with NaN (a debugging aid against reads of uninitialised
    # memory, which no op here makes): one extra kernel per allocation, ~800 of the ~5,300 aten calls of an RC13
    # training step (batch 3, profiled on the CPU), on a GPU where the step is launch-bound. The arithmetic stays
    # deterministic without it.
    torch.utils.deterministic.fill_uninitialized_memory = False
    torch.set_flush_denormal(True)     # denormals in Adam's moments make CPU matmuls ~20x slower
    torch.manual_seed(seed)
    return torch.device(device)


def set_arithmetic(deterministic: bool, tf32: bool) -> None:
    """How CUDA computes (the CPU's arithmetic is the same either way).

    deterministic: bit-reproducible runs; on CUDA the backward of every table gather (index_select) is then a
    sort-based accumulation instead of atomic adds. tf32: float32 matrix products on TF32 tensor cores (10-bit
    mantissa inputs, float32 accumulation; ~1e-3 relative per product) instead of full float32.
    """
    # The flag itself, not torch.use_deterministic_algorithms: in torch 2.13 that also copies it into
    # Inductor's config (its "skip on-device benchmarking" mode), importing torch._inductor to do so: ~1.1 s of
    # every train and evaluate process on the CPU machine, and no stage compiles with Inductor (the fused network
    # launches its Triton kernels itself). Where Inductor is
    # loaded already, its copy is kept in step as the public call would.
    torch._C._set_deterministic_algorithms(deterministic)
    inductor = sys.modules.get("torch._inductor.config")
    if inductor is not None:
        inductor.deterministic = deterministic
    torch.backends.cuda.matmul.fp32_precision = "tf32" if tf32 else "ieee"


def keep_resident(n_bytes: int, budget_gb: float | None, device: torch.device) -> bool:
    """Whether a dataset's frames (`n_bytes`) stay on the device: within `budget_gb`, or without one within
    half of what is free (the device's memory, or on the CPU the available RAM): the rest is the network's."""
    if budget_gb is None:
        free = (torch.cuda.mem_get_info(device)[0] if device.type == "cuda"
                else os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        return n_bytes <= free / 2
    return n_bytes <= budget_gb * 2 ** 30


def timing_device(device: torch.device) -> str:
    """Where a stage's times were measured, in words (eval.h5's and tradeoff.h5's `device`): the GPU's name, and
    how many jobs shared it where `jobs_per_gpu` let others run beside this one; the CPU with its threads."""
    if device.type != "cuda":
        return f"cpu, {torch.get_num_threads()} threads"
    shared = gpu_slots.jobs_sharing_the_gpu()
    beside = f" (one of {shared} jobs a GPU: times include the others' kernels)" if shared > 1 else ""
    return torch.cuda.get_device_name(device) + beside
