"""model.pt, written by the `train` stage: the state dict and everything needed to rebuild the network and to
recognise the operators it was trained on (docs/artifacts.md, section "model.pt"); and the file of the per-epoch
checkpoint of a running training, whose contents are model/training.py's business.

Both are read with `torch.load(weights_only=True)`, which builds tensors and plain values only: a file from
elsewhere is refused with one error, never unpickled into code."""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Mapping

import torch

from model.mesh_hierarchy import MeshHierarchy
from model.networks import NetworkSpec, NormalizedRegressor, build_network
from model.training import CHECKPOINT_FORMAT
from pipeline.artifacts.h5 import atomic_write
from pipeline.artifacts.operators import load_hierarchy
from pipeline.errors import PipelineError

MODEL_FORMAT = "trimesh-cnn/model-1"


def save_model(path: Path, model: NormalizedRegressor, spec: NetworkSpec, mesh: MeshHierarchy,
               extra: Mapping[str, Any]) -> None:
    state = {"format": MODEL_FORMAT, "spec": dataclasses.asdict(spec), "state_dict": model.state_dict(),
             "arch_expanded": str(model.net.arch), "parameter_count": model.net.parameter_count(),
             "operators": {"fingerprint": mesh.fingerprint(), "vertex_counts": mesh.vertex_counts}, **extra}
    _torch_save(path, state)


def load_model(path: str | os.PathLike, operators_path: str | os.PathLike,
               device: str) -> tuple[NormalizedRegressor, MeshHierarchy, dict]:
    """A trained model and the hierarchy it runs on, after checking the operators are those it was trained on."""
    if not Path(path).is_file():
        raise PipelineError(f"{path}: model file does not exist")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for a corrupt or foreign file
        raise PipelineError(f"{path}: not a readable model file ({type(err).__name__})") from None
    if not isinstance(state, dict) or state.get("format") != MODEL_FORMAT:
        raise PipelineError(f"{path}: not a model written by pipeline.train (format {MODEL_FORMAT})")
    spec = NetworkSpec(**state["spec"])
    trained = state["operators"]
    mesh = load_hierarchy(operators_path, spec.conv, len(trained["vertex_counts"]))
    if mesh.vertex_counts != trained["vertex_counts"]:
        raise PipelineError(f"{operators_path}: the model in {path} was trained on a mesh hierarchy with vertex "
                            f"counts {trained['vertex_counts']}, these operators have {mesh.vertex_counts}")
    if mesh.fingerprint() != trained["fingerprint"]:
        raise PipelineError(f"{operators_path}: same vertex counts but different operator tables than the ones "
                            f"the model in {path} was trained on")
    net = build_network(spec)
    model = NormalizedRegressor(net, torch.zeros(spec.in_channels), 1.0, 1.0)
    model.load_state_dict(state["state_dict"])
    return model.to(device).eval(), mesh.to(device), state


def write_checkpoint(path: Path, state: dict[str, Any]) -> None:
    _torch_save(path, state)


def read_checkpoint(path: Path) -> dict[str, Any] | None:
    """The training state saved at `path` by `write_checkpoint`, or None if there is none (yet, or any more:
    an identical run beside this one may have finished and removed it). Anything else at that path is refused
    rather than overwritten and later deleted: it is not this trainer's file."""
    refusal = f"{path}: not a training checkpoint ({CHECKPOINT_FORMAT}); remove it or choose another --checkpoint"
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        return None
    except Exception as err:  # torch raises many types for a foreign, damaged or code-carrying file
        raise PipelineError(f"{refusal} ({type(err).__name__})") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise PipelineError(refusal)
    return state


def _torch_save(path: Path, state: dict[str, Any]) -> None:
    with atomic_write(path) as f:
        torch.save(state, f)
