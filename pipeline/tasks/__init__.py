"""The learning problems of paper Table 2 as tasks of the shared learning stages: `upsampling` (Loop-subdivided
low-res run → high-res), `pose` (the mannequin's 208 pose scalars → cloth, over linear blend skinning) and `pca`
(K PCA coefficients of the high-res run → its details, over the PCA reconstruction) and `hand` (18 joint angles →
the FEM hand's skin, over linear blend skinning). docs/architecture.md,
"Applications", says where each lives."""
from __future__ import annotations

import torch

from model.training import Frames
from pipeline.artifacts.dataset import LearningData, frame_bytes
from pipeline.core.errors import PipelineError
from pipeline.core.torch_setup import keep_resident
from pipeline.tasks.hand import HandTask
from pipeline.tasks.pca import PcaTask
from pipeline.tasks.pose import PoseTask
from pipeline.tasks.task import Task
from pipeline.tasks.upsampling import UpsamplingTask

TASKS: dict[str, Task] = {task.name: task for task in (UpsamplingTask(), PoseTask(), PcaTask(), HandTask())}


def task_of(name: str, where: str) -> Task:
    """The task named `name` (as dataset.h5 or --task gives it); an error naming `where` otherwise."""
    if name not in TASKS:
        raise PipelineError(f"{where}: unknown task '{name}' (known: {', '.join(TASKS)})")
    return TASKS[name]


def frames_of(data: LearningData, device: torch.device | str) -> Frames:
    """Every frame of a dataset on `device` as its task's network reads them (Task.frames)."""
    return task_of(data.task, "dataset").frames(data, device)


def streams_frames(dataset: str, budget_gb: float | None, device: torch.device) -> tuple[bool, int]:
    """Whether `train` and `evaluate` read the frames of `dataset` from disk a batch at a time (a task that can,
    whose frames do not fit `budget_gb`, or half the free memory: keep_resident) rather than holding them on
    `device`; and the bytes of its frames."""
    name, n_bytes = frame_bytes(dataset)
    return task_of(name, dataset).streams and not keep_resident(n_bytes, budget_gb, device), n_bytes
