"""The learning problems of paper Table 2 as tasks of the shared learning stages: `upsampling` (Loop-subdivided
low-res run → high-res), `pose` (the mannequin's 208 pose scalars → cloth, over linear blend skinning) and `pca`
(K PCA coefficients of the high-res run → its details, over the PCA reconstruction) and `hand` (18 joint angles →
the FEM hand's skin, over linear blend skinning). docs/architecture.md,
"Applications", says where each lives."""
from __future__ import annotations

import torch

from model.training import Frames
from pipeline.artifacts.dataset import LearningData
from pipeline.core.errors import PipelineError
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
