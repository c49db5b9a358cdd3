"""Issue 35, the evaluate stage at scale: a dataset streamed from disk (--device-cache-gb 0) is evaluated into the
eval.h5, exports and stills a resident one gives, bit for bit on the CPU (same chunks of the same frames, same
arithmetic: model.scoring, model.streaming), errors by motion kind included; only the frames shown are held while
every frame is exported and stored (FrameOutputs); eval.h5's chunked writer refuses rows out of order and leaves
no file for an evaluation that did not finish. (A network that reads its previous output, refused on a streamed
dataset: tests/pipeline/test_train_stream.py.)"""
from __future__ import annotations

import json
import time

import h5py
import numpy as np
import pytest

from library_sheets import window, write_sheet_sequence
from model.scoring import CHUNK_FRAMES
from pipeline import dataset, evaluate, operators, train
from pipeline.artifacts.dataset import load_dataset
from pipeline.artifacts.evaluation import Evaluation, evaluation_output
from pipeline.core.h5 import config_of
from stage_inputs import stage

FRAMES = 40         # per sequence: 3 sequences, 120 frames, 4 chunks (CHUNK_FRAMES 32)
# Every frame exported and stored; two stills; no video (rendering one costs seconds and shows nothing new here).
EVALUATE = ["--render-frames", 2, "--video-frames", 0, "--export-frames", 0, "--timing-frames", 1, "--quiet"]
TIMING = {"inference_ms", "inference_ms_median", "phase_seconds"}   # wall times: what two runs do not share


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """Two library windows trained on and one held out (errors by motion kind), a model trained two epochs."""
    root = tmp_path_factory.mktemp("evaluate_stream")
    folders = [write_sheet_sequence(root, name, role, window(file, subject, category, 0.0, FRAMES * 0.1), FRAMES,
                                    amplitude)
               for name, role, (file, subject, category), amplitude in (
                   ("train_001-01_w00", "train", ("001/01.bvh", "1", "walk"), 1.3),
                   ("train_002-01_w00", "train", ("002/01.bvh", "2", "run"), 0.7),
                   ("held_out_003-01_w00", "held_out", ("003/01.bvh", "3", "walk"), 1.1))]
    stage(operators.main, root / "subdiv.h5", root / "operators.h5", "--conv", "RC7", "--levels", "4", "--quiet")
    stage(dataset.main, root / "subdiv.h5", root / "dataset.h5", *folders, "--quiet")
    stage(train.main, root / "dataset.h5", root / "operators.h5", root / "model.pt", root / "train.h5", "--arch",
          "D8 D16 D D16", "--conv", "RC7", "--inputs", "position,velocity", "--epochs", 1, "--quiet")
    return root


def _evaluate(root, out, *flags):
    stage(evaluate.main, root / "dataset.h5", root / "operators.h5", root / "model.pt", out / "eval.h5",
          out / "report.md", *EVALUATE, *flags)


def _contents(path) -> dict:
    """Every dataset and attribute of an HDF5 file by name, the wall times and the config left out."""
    found = {}
    with h5py.File(path) as f:
        f.visititems(lambda name, item: found.update({name: item[()]}) if isinstance(item, h5py.Dataset) else None)
        found.update({f"@{name}": value for name, value in f.attrs.items() if name != "config"})
        config = config_of(f)
    return {name: value for name, value in found.items() if name.lstrip("@") not in TIMING}, config


def test_a_streamed_evaluation_writes_what_a_resident_one_writes_holding_only_the_frames_shown(scene, tmp_path,
                                                                                                monkeypatch):
    held, chunks = [], []

    class Watched(evaluate.FrameOutputs):
        def __call__(self, ids, displacement):
            chunks.append(len(ids))
            super().__call__(ids, displacement)
            held.append(len(self.meshes))
    monkeypatch.setattr(evaluate, "FrameOutputs", Watched)
    runs = {}
    for mode, cache in (("resident", "64"), ("streamed", "0")):
        out = tmp_path / mode
        start = time.perf_counter()
        _evaluate(scene, out, "--device-cache-gb", cache)
        wall = time.perf_counter() - start
        runs[mode] = _contents(out / "eval.h5"), out
        # Where the stage's time went: every phase, in order, together no longer than the call.
        with h5py.File(out / "eval.h5") as f:
            phases = json.loads(f.attrs["phase_seconds"])
        assert list(phases) == ["load", "score", "time", "pictures", "videos", "exports and report"]
        assert all(seconds >= 0 for seconds in phases.values()) and sum(phases.values()) <= wall
    (resident, resident_config), resident_out = runs["resident"]
    (streamed, streamed_config), streamed_out = runs["streamed"]
    assert resident.keys() == streamed.keys() and {"predicted", "per_frame/network_l1",
                                                    "by_kind/category/held_out/network_l1"} <= resident.keys()
    for name, value in resident.items():
        assert np.array_equal(value, streamed[name], equal_nan=np.asarray(value).dtype.kind == "f"), name
    assert {key for key in resident_config if resident_config[key] != streamed_config[key]} == {
        "eval", "report", "device_cache_gb"}
    # Every frame exported, bit for bit; the stills drawn from the same meshes.
    n_frames = len(load_dataset(scene / "dataset.h5", frames=False).sequence)
    for pattern in ("export/predicted_obj/*.obj", "export/*.glb", "renders/frame_*.png"):
        names = sorted(path.relative_to(resident_out) for path in resident_out.glob(pattern))
        assert names == sorted(path.relative_to(streamed_out) for path in streamed_out.glob(pattern)) and names
        assert all((resident_out / name).read_bytes() == (streamed_out / name).read_bytes() for name in names)
    assert len(list(streamed_out.glob("export/predicted_obj/*.obj"))) == n_frames == len(resident["predicted"])
    # Held: the two stills alone, though every frame was stored and exported; chunks of CHUNK_FRAMES.
    assert chunks == 2 * [min(CHUNK_FRAMES, n_frames - first) for first in range(0, n_frames, CHUNK_FRAMES)]
    assert max(held) == 2 and held[-1] == 2


def _finish(out) -> None:
    out.finish(Evaluation({"network": {"test": {"l1": 1.0}}}, {}, None, np.ones(1), np.zeros(1), "cpu", 3, 10, 5))


def test_the_chunked_writer_takes_rows_in_order_once_each_and_leaves_no_file_unfinished(tmp_path):
    rows = np.arange(5 * 4 * 3, dtype=np.float32).reshape(5, 4, 3)
    path = tmp_path / "eval.h5"
    with evaluation_output(path, {}, rows.shape) as out:
        out.write_predicted(0, rows[:2])
        with pytest.raises(ValueError, match="after 2"):
            out.write_predicted(3, rows[3:])            # a gap
        out.write_predicted(2, rows[2:])
        with pytest.raises(ValueError, match="after 5"):
            out.write_predicted(4, rows[4:])            # again
        _finish(out)
    with h5py.File(path) as f:
        assert np.array_equal(f["predicted"][()], rows) and f.attrs["predictions_stored"]
    with pytest.raises(ValueError, match="4 of 5"):
        with evaluation_output(tmp_path / "unfinished.h5", {}, rows.shape) as out:
            out.write_predicted(0, rows[:4])
            _finish(out)
    with pytest.raises(RuntimeError, match="not finished"):
        with evaluation_output(tmp_path / "unfinished.h5", {}, rows.shape) as out:
            out.write_predicted(0, rows)
    assert not (tmp_path / "unfinished.h5").exists() and {p.name for p in tmp_path.iterdir()} == {"eval.h5"}
