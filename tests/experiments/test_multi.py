"""The multi-garment stages (experiments/multi/stage.py, experiments/multi/report.py) on two small synthetic garments of
different meshes: one garment trains what pipeline.train trains, bit for bit; the views share one network and
run in `evaluate`; a garment or operators it was not trained on, garments that disagree on the network, and a
foreign model file are one error each, leaving nothing behind; the report's table is the evaluations'."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from experiments.multi import report as multi_report
from experiments.multi import stage as multi
from pipeline import dataset, evaluate, operators, train
from pipeline.artifacts.evaluation import read_errors
from experiments.multi.table import read_multi_table
from pipeline.core.config import load_config, resolve_scene, write_settings
from stage_inputs import stage, write_waving_sheet

REPO = Path(__file__).resolve().parents[2]
GARMENTS = {"a": 5, "b": 4}       # grid resolution of each garment's low-res sheet


def _settings(folder: Path, **network) -> Path:
    """The smoke scene's settings sized to these meshes, with `network` overrides, in folder/settings.json."""
    resolved = resolve_scene(load_config(REPO / "workflow_config.yaml"), "patch")
    resolved["operators"].update(conv=["RC7"], levels=3)
    resolved["network"].update({"arch": "D8 D16 D D16", "conv": "RC7", "width": 1.0,
                                "inputs": ["velocity", "laplacian", "gravity"], "input_frame": "local",
                                "output_frame": "local", "frame_tangent": "gravity", **network})
    resolved["training"].update(epochs=2, lr=0.002, loss={"l1": 1.0, "l2": 0.5, "normal": 0.0})
    resolved["evaluation"].update(render_frames=0, video_frames=0, export_frames=1, timing_frames=2)
    write_settings(resolved, folder / "settings.json")
    return folder / "settings.json"


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """Per garment a folder with its simulations, operators, dataset and settings."""
    root = tmp_path_factory.mktemp("multi")
    for name, n in GARMENTS.items():
        folder = root / name
        folder.mkdir()
        write_waving_sheet(folder, n=n)
        _settings(folder)
        stage(operators.main, folder / "subdiv.h5", folder / "operators.h5", "--settings", folder / "settings.json",
              "--quiet")
        stage(dataset.main, folder / "subdiv.h5", folder / "dataset.h5", folder, "--quiet")
    return root


def garment_args(work: Path, names, out: Path) -> list:
    return [x for name in names for x in ("--garment", name, work / name / "settings.json",
                                          work / name / "dataset.h5", work / name / "operators.h5",
                                          out / name / "model.pt")]


@pytest.fixture(scope="module")
def trained(work) -> Path:
    out = work / "multi"
    stage(multi.main, "train", out / "model.pt", out / "train.h5", *garment_args(work, GARMENTS, out), "--quiet")
    return out


def test_with_one_garment_it_trains_what_pipeline_train_trains(work, tmp_path):
    stage(multi.main, "train", tmp_path / "multi.pt", tmp_path / "multi.h5",
          *garment_args(work, ["a"], tmp_path), "--quiet")
    stage(train.main, work / "a/dataset.h5", work / "a/operators.h5", tmp_path / "own.pt", tmp_path / "own.h5",
          "--settings", work / "a/settings.json", "--quiet")
    view, own = (torch.load(p, weights_only=True) for p in (tmp_path / "a/model.pt", tmp_path / "own.pt"))
    assert view["state_dict"].keys() == own["state_dict"].keys()
    for name, value in own["state_dict"].items():
        assert torch.equal(view["state_dict"][name], value), name
    assert view["operators"] == own["operators"] and view["spec"] == own["spec"]
    assert view["features"] == own["features"] and view["multi"] == {"garment": "a", "garments": ["a"]}


def test_the_views_share_one_network_and_evaluate_runs_them(work, trained):
    views = {name: torch.load(trained / name / "model.pt", weights_only=True) for name in GARMENTS}
    shared = torch.load(trained / "model.pt", weights_only=True)
    for name, view in views.items():
        weights = view["state_dict"]
        for key, value in shared["state_dict"].items():
            assert torch.equal(weights[f"net.{key}"], value), key
        for key, value in shared["normalisation"].items():
            assert torch.equal(weights[key], value), key
        assert torch.equal(weights["features.faces"], shared["garments"][name]["faces"])
        assert view["operators"] == shared["garments"][name]["operators"]
    assert views["a"]["state_dict"]["features.faces"].shape != views["b"]["state_dict"]["features.faces"].shape
    assert list(shared["garments"]) == ["a", "b"] and shared["training"]["garments"] == ["a", "b"]
    assert not list(trained.glob("*.ckpt"))
    for name in GARMENTS:
        stage(evaluate.main, work / name / "dataset.h5", work / name / "operators.h5", trained / name / "model.pt",
              trained / name / "eval.h5", trained / name / "report.md", "--settings", work / name / "settings.json",
              "--quiet")
        errors = read_errors(trained / name / "eval.h5")
        assert all(np.isfinite(v) for who in errors.values() for split in who.values() for v in split.values())


def _fails(capsys, main, *args) -> str:
    with pytest.raises(SystemExit) as exit_info:
        stage(main, *args)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1, err
    return err


def test_a_garment_or_operators_it_was_not_trained_on_are_refused(work, trained, tmp_path, capsys):
    out = tmp_path / "view.pt"
    err = _fails(capsys, multi.main, "view", trained / "model.pt", "c", work / "a/operators.h5", out)
    assert "trained on garments a, b; not on 'c'" in err
    err = _fails(capsys, multi.main, "view", trained / "model.pt", "a", work / "b/operators.h5", out)
    assert "trained on garment 'a' with a mesh hierarchy of vertex counts" in err
    err = _fails(capsys, multi.main, "view", trained / "model.pt", "a", work / "a/operators.h5", trained / "model.pt")
    assert "same file" in err
    err = _fails(capsys, multi.main, "view", trained / "a/model.pt", "a", work / "a/operators.h5", out)
    assert "not a multi-garment model" in err
    damaged = torch.load(trained / "model.pt", weights_only=True)
    del damaged["garments"]["b"]["operators"]
    torch.save(damaged, tmp_path / "damaged.pt")
    err = _fails(capsys, multi.main, "view", tmp_path / "damaged.pt", "a", work / "a/operators.h5", out)
    assert "damaged multi-garment model file" in err
    assert not out.exists()
    # The garment's own view, made again, is the one training wrote.
    stage(multi.main, "view", trained / "model.pt", "b", work / "b/operators.h5", out)
    again, written = (torch.load(p, weights_only=True) for p in (out, trained / "b/model.pt"))
    assert all(torch.equal(again["state_dict"][k], v) for k, v in written["state_dict"].items())
    # A view on another garment's dataset: evaluate's own check.
    err = _fails(capsys, evaluate.main, work / "b/dataset.h5", work / "b/operators.h5", trained / "a/model.pt",
                 tmp_path / "e.h5", tmp_path / "r.md", "--quiet")
    assert "a/model.pt" in err and not (tmp_path / "e.h5").exists()


def test_garments_that_disagree_on_the_network_are_one_error_naming_the_setting(work, tmp_path, capsys):
    other = tmp_path / "other"
    other.mkdir()
    _settings(other, width=0.5)
    args = garment_args(work, GARMENTS, tmp_path)
    args[args.index(work / "b/settings.json")] = other / "settings.json"
    err = _fails(capsys, multi.main, "train", tmp_path / "m.pt", tmp_path / "t.h5", *args, "--quiet")
    assert "network.width 0.5 (not 1.0) differs" in err
    err = _fails(capsys, multi.main, "train", tmp_path / "m.pt", tmp_path / "t.h5",
                 *garment_args(work, ["a", "a"], tmp_path), "--quiet")
    assert "give each garment once" in err
    assert not list(tmp_path.glob("**/*.pt"))


def test_the_report_table_is_the_evaluations_and_unlike_networks_are_refused(work, trained, tmp_path, capsys):
    """Each garment's own network is pipeline.train's on its settings; the table holds each eval.h5's figures."""
    for name in GARMENTS:
        own = tmp_path / name
        stage(train.main, work / name / "dataset.h5", work / name / "operators.h5", own / "model.pt",
              own / "train.h5", "--settings", work / name / "settings.json", "--quiet")
        stage(evaluate.main, work / name / "dataset.h5", work / name / "operators.h5", own / "model.pt",
              own / "eval.h5", own / "report.md", "--settings", work / name / "settings.json", "--quiet")
        if not (trained / name / "eval.h5").exists():
            stage(evaluate.main, work / name / "dataset.h5", work / name / "operators.h5",
                  trained / name / "model.pt", trained / name / "eval.h5", trained / name / "report.md",
                  "--settings", work / name / "settings.json", "--quiet")
    outputs = [tmp_path / "multi.h5", tmp_path / "curve.png", tmp_path / "report.md"]
    pairs = [x for name in GARMENTS
             for x in ("--garment", name, trained / name / "eval.h5", tmp_path / name / "eval.h5")]
    stage(multi_report.main, *outputs, "--model", trained / "model.pt", "--train-log", trained / "train.h5", *pairs)
    table = read_multi_table(tmp_path / "multi.h5")
    assert table.garments == ["a", "b"] and table.splits == ["train", "test"]
    for k, name in enumerate(GARMENTS):
        shared, own = read_errors(trained / name / "eval.h5"), read_errors(tmp_path / name / "eval.h5")
        for split in table.splits:
            for term in ("l1", "l2"):
                assert table.errors["shared"][split][term][k] == shared["network"][split][term]
                assert table.errors["own"][split][term][k] == own["network"][split][term]
                assert table.errors["predictor"][split][term][k] == own["predictor"][split][term]
    assert list(table.vertices) == [289, 169]        # (4 (n - 1) + 1)^2 after two Loop subdivisions
    report = (tmp_path / "report.md").read_text()
    assert "| a | shared network (every garment) |" in report and "](curve.png)" in report
    assert (tmp_path / "curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # The own and shared evaluations of a garment swapped for another garment's: other frames, refused.
    swapped = [x for name, other in (("a", "b"), ("b", "a"))
               for x in ("--garment", name, trained / name / "eval.h5", tmp_path / other / "eval.h5")]
    for path in outputs:
        path.unlink()
    err = _fails(capsys, multi_report.main, *outputs, "--model", trained / "model.pt", "--train-log",
                 trained / "train.h5", *swapped)
    assert "not evaluations of the same frames" in err and not any(p.exists() for p in outputs)
