"""The learning stages end to end (dataset → train → evaluate) on small synthetic simulation artifacts, with the
operators built by meshops; plus resume-after-kill, the clear errors of bad input, and settings.json as the
defaults of the stages' flags."""
from __future__ import annotations

import base64
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import imageio_ffmpeg
import numpy as np
import pytest
import torch
import trimesh

from experiments.tradeoff import stage as tradeoff
from pipeline import dataset, evaluate, operators, train
from pipeline.tasks import timing as tradeoff_timing
from pipeline.artifacts.evaluation import read_errors
from pipeline.artifacts.dataset import load_dataset
from pipeline.core.errors import PipelineError
from experiments.tradeoff.stage import Network
from pipeline.core.h5 import atomic_h5, config_of, read_csr
from pipeline.core.config import load_config, resolve_scene, write_settings
from stage_inputs import N_FRAMES, stage, write_sequence_scene, write_waving_sheet

REPO = Path(__file__).resolve().parents[2]
ARCH = ["--arch", "D8 D16 D D16", "--conv", "RC7"]


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("learning")
    write_waving_sheet(folder)
    stage(operators.main, folder / "subdiv.h5", folder / "operators.h5", "--conv", "RC7", "--levels", "4", "--quiet")
    stage(dataset.main, folder / "subdiv.h5", folder / "dataset.h5", folder, "--quiet")
    return folder


@pytest.fixture(scope="module")
def trained(work) -> Path:
    stage(train.main, work / "dataset.h5", work / "operators.h5", work / "model.pt", work / "train.h5", *ARCH,
          "--epochs", "20", "--quiet")
    return work


def test_dataset_is_the_low_res_run_s_and_the_displacement_from_s_x_low(work):
    with h5py.File(work / "subdiv.h5") as f:
        subdivision = read_csr(f, "S")
    with h5py.File(work / "sim_low.h5") as f:
        low = f["positions"][()].astype(np.float64)
    with h5py.File(work / "sim_high.h5") as f:
        high = f["positions"][()].astype(np.float64)
    with h5py.File(work / "dataset.h5") as f:
        stored_low, target = f["low/positions"][()], f["target"][()]
        stored_S = read_csr(f, "subdivision")
        train_ids, test_ids = f["split/train"][()], f["split/test"][()]
        assert "input" not in f and "predictor" not in f          # S x_low is computed where it is used
        assert f.attrs["frame"] == "world" and f.attrs["format"] == "trimesh-cnn/dataset-2"
    assert (stored_S != subdivision).nnz == 0
    np.testing.assert_allclose(stored_low, low, atol=1e-6)
    expected = np.einsum("hl,flc->fhc", subdivision.toarray(), low)
    predictor = load_dataset(work / "dataset.h5").predictor
    np.testing.assert_allclose(predictor, expected, atol=1e-6)
    np.testing.assert_allclose(predictor + target, high, atol=1e-6)
    assert len(test_ids) == 1 and len(train_ids) == N_FRAMES - 1      # round(10 % of 12)
    assert np.array_equal(np.sort(np.concatenate([train_ids, test_ids])), np.arange(N_FRAMES))


def test_torso_frame_removes_a_rigid_motion(work, tmp_path):
    angles = np.linspace(0, 1.0, N_FRAMES)
    rotations = np.stack([[[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]] for a in angles])
    shifts = np.stack([np.array([0.3, -0.2, 1.0]) * a for a in angles])
    write_waving_sheet(tmp_path, transform=lambda x, f: x @ rotations[f].T + shifts[f])
    transforms = np.tile(np.eye(4), (N_FRAMES, 1, 1))
    transforms[:, :3, :3], transforms[:, :3, 3] = rotations, shifts
    write_sequence_scene(tmp_path, torso_transforms=transforms)
    stage(dataset.main, tmp_path / "subdiv.h5", tmp_path / "dataset.h5", tmp_path, "--frame", "torso", "--quiet")
    with h5py.File(tmp_path / "dataset.h5") as moved, h5py.File(work / "dataset.h5") as still:
        np.testing.assert_allclose(moved["low/positions"][()], still["low/positions"][()], atol=1e-5)
        np.testing.assert_allclose(moved["target"][()], still["target"][()], atol=1e-5)


def test_torso_frame_without_transforms_is_a_clear_error(work, tmp_path, capsys):
    write_waving_sheet(tmp_path)
    write_sequence_scene(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        stage(dataset.main, work / "subdiv.h5", tmp_path / "d.h5", tmp_path, "--frame", "torso")
    assert exit_info.value.code == 2
    assert "torso_transforms" in capsys.readouterr().err and not (tmp_path / "d.h5").exists()


def test_training_writes_model_and_falling_loss_curves(trained):
    assert not (trained / "model.pt.ckpt").exists()            # removed once the outputs are complete
    with h5py.File(trained / "train.h5") as f:
        train_loss, test_loss = f["epoch/train_total"][()], f["epoch/test_total"][()]
        assert f.attrs["parameter_count"] == 10_349 and len(train_loss) == 20
    assert train_loss[-1] < 0.6 * train_loss[0] and test_loss[-1] < 0.8 * test_loss[0]
    state = torch.load(trained / "model.pt", weights_only=True)
    assert state["spec"]["arch"] == "D8 D16 D D16" and state["operators"]["vertex_counts"][0] == 289


def test_evaluation_errors_renders_and_exports(trained):
    out = trained / "eval"
    stage(evaluate.main, trained / "dataset.h5", trained / "operators.h5", trained / "model.pt", out / "eval.h5",
          out / "report.md", "--render-frames", "1", "--timing-frames", "3", "--video-frames", "0", "--quiet")
    data = load_dataset(trained / "dataset.h5")
    inputs, target, test_ids, faces = data.predictor, data.targets, data.test, data.faces
    with h5py.File(out / "eval.h5") as f:
        predicted = f["predicted"][()]
        errors = {k: f[f"errors/{k}"][()] for k in ("network/test/l1", "network/test/l2", "predictor/test/l1",
                                                      "predictor/test/l2")}
        assert f["inference_ms"].shape == (1,) or np.all(f["inference_ms"][()] > 0)
        assert "inference_ms_fused" not in f      # the fused bf16 network runs on CUDA only: not timed here
    truth = inputs + target
    difference = (predicted - truth)[test_ids].astype(np.float64)
    assert np.isclose(errors["network/test/l1"], np.abs(difference).mean(), rtol=1e-4)
    assert np.isclose(errors["network/test/l2"], np.sqrt((difference ** 2).sum(-1).mean()), rtol=1e-4)
    assert np.isclose(errors["predictor/test/l1"], np.abs(target[test_ids]).mean(), rtol=1e-4)
    assert errors["network/test/l1"] < errors["predictor/test/l1"]       # the network beats Loop subdivision
    report = (out / "report.md").read_text()
    assert "10,349 learnable parameters" in report and "Loop subdivision alone" in report
    assert "| learning-rate schedule | constant |" in report and "| input noise (std, normalised units) | none |" in report
    assert "| optimiser step | eager, deterministic, float32 products |" in report
    pictures = sorted((out / "renders").glob("frame_*.png"))
    assert len(pictures) == 1 and f"]({pictures[0].relative_to(out)})" in report
    obj = trimesh.load(out / "export/predicted_obj/frame_0003.obj", process=False)
    np.testing.assert_allclose(obj.vertices, predicted[3], atol=1e-5)
    assert np.array_equal(obj.faces, faces)
    scene = trimesh.load(next((out / "export").glob("*.glb")))
    assert set(scene.geometry) == {"low_res_input", "ground_truth", "network_output"}
    assert not (out / "videos").exists() and not (out / "report.html").exists()    # --video-frames 0, no --html


def test_an_evaluation_without_predictions_has_the_same_errors_and_no_positions(trained):
    full, lean = trained / "eval", trained / "lean"
    if not (full / "eval.h5").exists():
        stage(evaluate.main, trained / "dataset.h5", trained / "operators.h5", trained / "model.pt",
              full / "eval.h5", full / "report.md", "--render-frames", "0", "--video-frames", "0", "--quiet")
    stage(evaluate.main, trained / "dataset.h5", trained / "operators.h5", trained / "model.pt", lean / "eval.h5",
          lean / "report.md", "--render-frames", "0", "--timing-frames", "1", "--video-frames", "0",
          "--export-frames", "1", "--no-predictions", "--quiet")
    with h5py.File(full / "eval.h5") as f, h5py.File(lean / "eval.h5") as g:
        assert "predicted" in f and f.attrs["predictions_stored"]
        assert "predicted" not in g and not g.attrs["predictions_stored"]
        assert read_errors(full / "eval.h5") == read_errors(lean / "eval.h5")
        for name in f["per_frame"]:
            np.testing.assert_array_equal(g[f"per_frame/{name}"][()], f[f"per_frame/{name}"][()])
    assert "eval.h5: errors, per-frame errors, inference times" in (lean / "report.md").read_text()
    assert "eval.h5: errors, per-frame errors, predicted positions, inference times" in (full / "report.md").read_text()


def data_uri_bytes(uri: str) -> bytes:
    assert uri.startswith("data:") and ";base64," in uri
    return base64.b64decode(uri.split(";base64,", 1)[1])


def test_the_tradeoff_times_each_model_once_on_the_deployment_path_and_pairs_it_with_its_own_evaluation(
        trained, tmp_path):
    """experiments.tradeoff.time_networks: one median per distinct model (a model fed several budgets is timed once),
    finite and positive, the fused network's NaN on the CPU; an evaluation of a network of another size is refused (its errors would be paired with
    another network's ms)."""
    lean = trained / "lean"
    if not (lean / "eval.h5").exists():
        stage(evaluate.main, trained / "dataset.h5", trained / "operators.h5", trained / "model.pt", lean / "eval.h5",
              lean / "report.md", "--render-frames", "0", "--video-frames", "0", "--no-predictions", "--quiet")
    model = str(trained / "model.pt")
    network = Network(str(lean / "eval.h5"), model)
    calls = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(tradeoff, "time_inference", lambda *a: calls.append(a) or tradeoff_timing.time_inference(*a))
        ms = tradeoff.time_networks([network, network], str(trained / "dataset.h5"), str(trained / "operators.h5"),
                                    torch.device("cpu"), 4)
    test_frames = load_dataset(trained / "dataset.h5").test
    timed = calls[0][3].tolist()
    assert list(ms) == [model] and len(calls) == 1
    assert set(timed) <= set(test_frames.tolist()) and len(timed) == min(4, len(test_frames))
    assert np.isfinite(ms[model].fp32) and ms[model].fp32 > 0
    assert np.isnan(ms[model].fused) and np.isnan(ms[model].fused_error)      # the fused network: CUDA only
    with h5py.File(lean / "eval.h5") as f:
        other = tmp_path / "other.h5"
        with h5py.File(other, "w") as g:
            for name in f:
                f.copy(f[name], g)
            g.attrs.update(f.attrs)
            g.attrs["parameter_count"] = int(f.attrs["parameter_count"]) + 1
    with pytest.raises(PipelineError, match="not that model's evaluation"):
        tradeoff.time_networks([Network(str(other), model)], str(trained / "dataset.h5"),
                               str(trained / "operators.h5"), torch.device("cpu"), 2)


def test_evaluation_report_page_embeds_its_pictures_and_videos(trained):
    """report.html holds the tables, the stills, the plots (the training curve from --train-log) and the videos,
    each embedded byte for byte; report.md links the same files; a video decodes to its frame count, at the
    scene's frame rate."""
    out = trained / "html"
    stage(evaluate.main, trained / "dataset.h5", trained / "operators.h5", trained / "model.pt", out / "eval.h5",
          out / "report.md", "--html", out / "report.html", "--train-log", trained / "train.h5",
          "--render-frames", "1", "--video-frames", "5", "--timing-frames", "1", "--quiet")
    page = (out / "report.html").read_text()
    sources = re.findall(r'<(?:img|video) src="([^"]+)"', page)
    files = sorted((out / "renders").glob("*.png")) + sorted((out / "videos").iterdir())
    assert [p.name for p in files] == ["error_over_time.png", "frame_0009.png", "training_curve.png", "test.mp4"]
    assert sorted(data_uri_bytes(uri) for uri in sources) == sorted(p.read_bytes() for p in files)
    assert "10,349 learnable parameters" in page and page.count("<table>") == 3     # errors, inputs, training
    report = (out / "report.md").read_text()
    assert all(f"]({p.relative_to(out)})" in report for p in files)
    assert "](export/predicted_obj)" in report and 'href="export/predicted_obj"' in page
    # The synthetic sheet's one sequence of 12 frames (dt 0.1 s) has one test frame: 5 frames around it.
    reader = imageio_ffmpeg.read_frames(str(out / "videos" / "test.mp4"))
    meta = next(reader)
    assert meta["fps"] == 10 and sum(1 for _ in reader) == 5
    with h5py.File(trained / "dataset.h5") as f:
        assert f["split/test"][()].tolist() == [9]
    assert "Frames 5-9 of a training sequence, 1 of them test frames" in report


def test_evaluation_failing_midway_leaves_nothing_behind(trained, tmp_path, monkeypatch):
    """Renders and exports are written before the videos: a failure encoding a video must take them away too,
    and any folder of an earlier run stays as it was."""
    out = tmp_path / "out"
    (out / "renders").mkdir(parents=True)
    (out / "renders" / "earlier.png").write_bytes(b"an earlier run's")

    def failing(frames, fps):
        next(iter(frames))                       # the first video frame is rendered, then the encoder fails
        raise OSError("disk full")

    monkeypatch.setattr(evaluate, "encode_animation", failing)
    with pytest.raises(OSError, match="disk full"):
        stage(evaluate.main, trained / "dataset.h5", trained / "operators.h5", trained / "model.pt",
              out / "eval.h5", out / "report.md", "--html", out / "report.html", "--render-frames", "1",
              "--video-frames", "2", "--timing-frames", "1", "--quiet")
    assert sorted(p.name for p in out.iterdir()) == ["renders"]
    assert [p.name for p in (out / "renders").iterdir()] == ["earlier.png"]


def test_resume_after_kill_ends_like_an_uninterrupted_run(work, tmp_path):
    epochs = ["--epochs", "24", "--quiet"]
    paths = [work / "dataset.h5", work / "operators.h5"]
    killed = subprocess.Popen([sys.executable, "-m", "pipeline.train", *map(str, paths), str(tmp_path / "a.pt"),
                               str(tmp_path / "a.h5"), *ARCH, *epochs], cwd=REPO, start_new_session=True)
    checkpoint = tmp_path / "a.pt.ckpt"
    deadline = time.monotonic() + 60
    while not checkpoint.exists() and killed.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    os.killpg(killed.pid, signal.SIGKILL)
    killed.wait()
    assert checkpoint.exists() and not (tmp_path / "a.pt").exists(), "the run must be killed mid-training"
    stage(train.main, *paths, tmp_path / "a.pt", tmp_path / "a.h5", *ARCH, *epochs)
    stage(train.main, *paths, tmp_path / "b.pt", tmp_path / "b.h5", *ARCH, *epochs)
    with h5py.File(tmp_path / "a.h5") as resumed, h5py.File(tmp_path / "b.h5") as uninterrupted:
        assert resumed.attrs["resumed_from_epoch"] > 0 and uninterrupted.attrs["resumed_from_epoch"] == 0
        np.testing.assert_allclose(resumed["epoch/train_total"][()], uninterrupted["epoch/train_total"][()],
                                   rtol=1e-6)
    a = torch.load(tmp_path / "a.pt", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "b.pt", weights_only=True)["state_dict"]
    for name in b:
        torch.testing.assert_close(a[name], b[name], rtol=1e-6, atol=1e-7)


def test_cuda_arithmetic_keys_leave_cpu_training_unchanged(work, tmp_path):
    """training.deterministic and training.tf32 choose CUDA kernels only: on the CPU the same weights come out,
    and the log records what was asked for."""
    paths, epochs = [work / "dataset.h5", work / "operators.h5"], ["--epochs", "3", "--quiet"]
    stage(train.main, *paths, tmp_path / "a.pt", tmp_path / "a.h5", *ARCH, *epochs, "--deterministic", "false",
          "--tf32", "true")
    assert not torch.are_deterministic_algorithms_enabled()
    assert torch.backends.cuda.matmul.fp32_precision == "tf32"
    stage(train.main, *paths, tmp_path / "b.pt", tmp_path / "b.h5", *ARCH, *epochs)
    assert torch.are_deterministic_algorithms_enabled()
    assert torch.backends.cuda.matmul.fp32_precision == "ieee"
    with h5py.File(tmp_path / "a.h5") as a, h5py.File(tmp_path / "b.h5") as b:
        assert (config_of(a)["deterministic"], config_of(a)["tf32"]) == (False, True)
        assert (config_of(b)["deterministic"], config_of(b)["tf32"]) == (True, False)
    a = torch.load(tmp_path / "a.pt", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "b.pt", weights_only=True)["state_dict"]
    for name in b:
        torch.testing.assert_close(a[name], b[name], rtol=0, atol=0)


def test_training_options_of_a_hand_made_model_file_are_shown_only_when_well_typed():
    rows = evaluate._training_option_rows({"lr_schedule": "cosine", "input_noise": 0.2, "cuda_graph": True,
                                           "deterministic": False, "tf32": True})
    assert rows == [["learning-rate schedule", "cosine down to 1 %"], ["input noise (std, normalised units)", "0.2"],
                    ["optimiser step", "one CUDA graph, atomic adds (not bit-reproducible), TF32 products"]]
    hostile = {"lr_schedule": "<script>", "input_noise": float("nan"), "cuda_graph": 1, "deterministic": "yes",
               "tf32": None}
    assert evaluate._training_option_rows(hostile) == [] and evaluate._training_option_rows({}) == []


def test_model_on_other_operators_is_one_clear_error(trained, tmp_path, capsys):
    other = tmp_path / "other"
    other.mkdir()
    write_waving_sheet(other, n=4)
    stage(operators.main, other / "subdiv.h5", other / "operators.h5", "--conv", "RC7", "--levels", "4", "--quiet")
    with pytest.raises(SystemExit) as exit_info:
        stage(evaluate.main, trained / "dataset.h5", other / "operators.h5", trained / "model.pt",
              tmp_path / "eval.h5", tmp_path / "report.md", "--quiet")
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "was trained on a mesh hierarchy with vertex counts" in err


@pytest.mark.parametrize("bad, message", [
    (["--arch", "D8 Q"], "token 2 'Q'"),
    (["--arch", "D8 D D D D D D8", "--conv", "RC7"], "needs 7 mesh levels"),
    (["--arch", "D8", "--conv", "EC13"], "no 'EC13' convolution tables"),
    (["--arch", "U8 U3", "--conv", "RC7"], "encoder-decoder, written with D tokens"),
])
def test_bad_training_options_are_one_clear_error(work, tmp_path, capsys, bad, message):
    with pytest.raises(SystemExit) as exit_info:
        stage(train.main, work / "dataset.h5", work / "operators.h5", tmp_path / "m.pt", tmp_path / "t.h5", *bad)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and not (tmp_path / "m.pt").exists()


def test_training_without_arch_is_a_usage_error(work, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        stage(train.main, work / "dataset.h5", work / "operators.h5", tmp_path / "m.pt", tmp_path / "t.h5")
    assert exit_info.value.code == 2
    assert "the following arguments are required: --arch" in capsys.readouterr().err


@pytest.fixture(scope="module")
def settings(work) -> dict:
    """The smoke scene's resolved settings, sized to these tests' mesh and network, in work/settings.json."""
    resolved = resolve_scene(load_config(REPO / "workflow_config.yaml"), "patch")
    resolved["operators"].update(conv=["RC7"], levels=4)
    resolved["network"].update(arch="D8 D16 D D16", conv="RC7", width=1, inputs=["velocity", "laplacian", "gravity"],
                               input_frame="local", output_frame="local", frame_tangent="gravity")
    resolved["training"].update(epochs=2, lr=0.002, loss={"l1": 1.0, "l2": 0.5, "normal": 0.0})
    resolved["evaluation"].update(render_frames=1, video_frames=2, export_frames=2, timing_frames=2)
    write_settings(resolved, work / "settings.json")
    return resolved


def _spelled_out(settings: dict) -> dict[str, list]:
    """Each stage's flags holding the values of `settings`, as a shell command would spell them."""
    network, training, loss = settings["network"], settings["training"], settings["training"]["loss"]
    evaluation = settings["evaluation"]
    return {
        "operators": ["--conv", ",".join(settings["operators"]["conv"]), "--levels", settings["operators"]["levels"]],
        "dataset": ["--frame", settings["dataset"]["frame"], "--test-fraction", settings["dataset"]["test_fraction"],
                    "--seed", settings["dataset"]["seed"]],
        "train": ["--arch", network["arch"], "--conv", network["conv"], "--pool", network["pool"], "--width",
                  network["width"], "--inputs", ",".join(network["inputs"]), "--input-frame",
                  network["input_frame"], "--output-frame", network["output_frame"], "--frame-tangent",
                  network["frame_tangent"], "--epochs", training["epochs"], "--batch-size", training["batch_size"], "--lr",
                  training["lr"], "--seed", training["seed"], "--loss-l1", loss["l1"], "--loss-l2", loss["l2"],
                  "--loss-normal", loss["normal"], "--device", settings["device"]],
        "evaluate": ["--render-frames", evaluation["render_frames"], "--video-frames", evaluation["video_frames"],
                     "--export-frames", evaluation["export_frames"], "--timing-frames", evaluation["timing_frames"],
                     "--device", settings["device"]],
    }


def _made(artifact: Path, model: Path | None) -> tuple:
    """What a stage run made: its artifact's config attr, a split if any, and the model it trained if any."""
    with h5py.File(artifact) as f:
        split = f["split/train"][()] if "split/train" in f else None
        return config_of(f), split, torch.load(model, weights_only=True) if model else None


def test_settings_make_the_artifacts_their_flags_make(work, settings, tmp_path):
    """Each stage run with --settings records the same config, and makes the same data, as with the flags."""
    flags, from_settings = _spelled_out(settings), ["--settings", work / "settings.json"]
    dataset_h5, operators_h5, model_pt = tmp_path / "dataset.h5", tmp_path / "operators.h5", tmp_path / "model.pt"
    runs = {
        "operators": (operators.main, [work / "subdiv.h5", operators_h5], operators_h5, None),
        "dataset": (dataset.main, [work / "subdiv.h5", dataset_h5, work], dataset_h5, None),
        "train": (train.main, [dataset_h5, operators_h5, model_pt, tmp_path / "train.h5"], tmp_path / "train.h5",
                  model_pt),
        "evaluate": (evaluate.main, [dataset_h5, operators_h5, model_pt, tmp_path / "eval.h5",
                                     tmp_path / "report.md"], tmp_path / "eval.h5", None),
    }
    configs = {}
    for name, (main, paths, artifact, model) in runs.items():
        stage(main, *paths, *flags[name], "--quiet")
        config_a, split_a, model_a = _made(artifact, model)
        stage(main, *paths, *from_settings, "--quiet")        # the same paths: it overwrites the run above
        configs[name], split_b, model_b = _made(artifact, model)
        assert configs[name] == config_a, name
        assert split_a is None or np.array_equal(split_a, split_b)
        if model:
            assert model_a["training"] == model_b["training"] and model_a["spec"] == model_b["spec"]
            assert all(torch.equal(model_a["state_dict"][k], model_b["state_dict"][k]) for k in model_a["state_dict"])
    assert configs["train"]["width"] == 1.0 and configs["train"]["lr"] == 0.002 and configs["train"]["epochs"] == 2
    assert configs["train"]["inputs"] == "velocity,laplacian,gravity" and configs["train"]["output_frame"] == "local"
    assert configs["operators"]["conv"] == ["RC7"] and configs["evaluate"]["timing_frames"] == 2
    assert not any("settings" in config for config in configs.values())


def test_a_flag_given_by_hand_overrides_the_settings(work, settings, tmp_path):
    stage(dataset.main, work / "subdiv.h5", tmp_path / "dataset.h5", work,
          "--settings", work / "settings.json", "--seed", "7", "--quiet")
    with h5py.File(tmp_path / "dataset.h5") as f:
        assert f.attrs["split_seed"] == config_of(f)["seed"] == 7
        assert f.attrs["test_fraction"] == settings["dataset"]["test_fraction"]
