"""Item 8 of issue 41: a model.pt or checkpoint may hold no more than its own size. A 1.4 MB file held a
(10^9, 3) tensor of stride 0 over three numbers, which evaluate materialised (7.5 GiB, a MemoryError traceback),
and a 3.3 MB zip bomb inflated to 2 GB with rc 0. Both are refused, as one error naming the file, before any
tensor is built from them."""
from __future__ import annotations

import zipfile
from pathlib import Path

import pytest
import torch

from model.training import CHECKPOINT_FORMAT
from pipeline.artifacts.model import MODEL_FORMAT, read_checkpoint, read_model_state
from pipeline.core.errors import PipelineError


def _save(path: Path, weight: torch.Tensor, format: str) -> Path:
    torch.save({"format": format, "state_dict": {"weight": weight}}, path)
    return path


def _deflated(path: Path) -> Path:
    """The same archive with every member compressed, as torch.save never writes it."""
    packed = path.with_name("packed.pt")
    with zipfile.ZipFile(path) as plain, zipfile.ZipFile(packed, "w", zipfile.ZIP_DEFLATED) as out:
        for member in plain.infolist():
            out.writestr(member.filename, plain.read(member))
    return packed


def _read(path: Path, format: str) -> dict:
    return read_model_state(path, format, "a model") if format == MODEL_FORMAT else read_checkpoint(path)


@pytest.mark.parametrize("format", [MODEL_FORMAT, CHECKPOINT_FORMAT])
def test_an_expanded_tensor_is_refused(tmp_path, format):
    path = _save(tmp_path / "model.pt", torch.zeros(3).expand(10**9, 3), format)
    assert path.stat().st_size < 10_000
    with pytest.raises(PipelineError, match=r"\(a tensor of shape \(1000000000, 3\) is not stored element by "):
        _read(path, format)


@pytest.mark.parametrize("format", [MODEL_FORMAT, CHECKPOINT_FORMAT])
def test_a_zip_bomb_is_refused_before_it_inflates(tmp_path, format):
    bomb = _deflated(_save(tmp_path / "model.pt", torch.zeros(16 << 20), format))    # 64 MiB of zeros
    assert bomb.stat().st_size < 1 << 20
    with pytest.raises(PipelineError, match=rf"^{bomb}: .*compressed members, which torch.save never writes"):
        _read(bomb, format)


@pytest.mark.parametrize("format", [MODEL_FORMAT, CHECKPOINT_FORMAT])
def test_what_torch_save_writes_is_read(tmp_path, format):
    weight = torch.arange(12.0).reshape(3, 4)
    state = _read(_save(tmp_path / "model.pt", weight.t().contiguous(), format), format)
    assert torch.equal(state["state_dict"]["weight"], weight.t())
