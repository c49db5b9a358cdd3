"""`results/<scene>/pose/` and `results/<scene>/pca/` end to end on the tiny pants of workflow_runs.py: each
folder's artifacts, finite errors, each network below its predictor on the frames it trained on, the PCA table;
a grid scene asked for pose says in one line that it has no pose input; neither target is part of
`results/<scene>/`. A decoder small enough for seconds: the tiny mesh has 6 levels."""
import h5py
import numpy as np
import pytest
import yaml

from workflow_runs import build, planned_counts, snakemake, tail, tiny_pants

DECODER = {"network": {"arch": "U32 U U32 U16 U3"}, "operators": {"levels": 5}, "training": {"epochs": 10},
           "evaluation": {"render_frames": 1, "video_frames": 1}}    # a still and two one-frame videos each
PRODUCTS = ("settings.json", "dataset.h5", "model.pt", "train.h5", "eval.h5", "report.md", "report.html")


@pytest.fixture(scope="module")
def applications(tmp_path_factory):
    """Both targets built in one run (they share the scene's sequences, each shard of them one batch job). In a
    folder of their own: the scene's upsampling stages must not run."""
    workdir = tmp_path_factory.mktemp("applications")
    config = tiny_pants(workdir, shard=2)
    overlay = yaml.safe_load(config.read_text())
    overlay["profiles"]["cpu"]["scenes"]["pants"]["applications"] = {
        "pose": DECODER, "pca": {"components": [4, 8], **DECODER}}
    config.write_text(yaml.safe_dump(overlay))
    run = build(workdir, "results/pants/pose/", "results/pants/pca/", "--configfile", str(config))
    assert run.returncode == 0, tail(run)
    return workdir / "results" / "pants"


def errors_of(folder):
    with h5py.File(folder / "eval.h5") as f:
        return {who: {split: {term: f[f"errors/{who}/{split}/{term}"][()] for term in ("l1", "l2")}
                      for split in f[f"errors/{who}"]} for who in ("network", "predictor")}


@pytest.mark.parametrize("folder", ["pose", "pca/k4", "pca/k8"])
def test_each_model_folder_holds_its_artifacts_and_beats_its_predictor_on_the_training_frames(applications, folder):
    out = applications / folder
    assert all((out / name).is_file() for name in PRODUCTS[1:]), sorted(p.name for p in out.iterdir())
    assert list((out / "renders").glob("frame_*.png")) and list((out / "videos").glob("*.mp4"))
    task, k = folder.split("/k") if "/k" in folder else (folder, None)
    with h5py.File(out / "dataset.h5") as f:
        assert f.attrs["task"] == task and f["input"].shape[1] == (208 if task == "pose" else int(k))
    errors = errors_of(out)
    assert set(errors["network"]) == {"train", "test", "held_out"}
    assert all(np.isfinite(v) for who in errors.values() for split in who.values() for v in split.values())
    assert errors["network"]["train"]["l1"] < errors["predictor"]["train"]["l1"]
    report = (out / "report.md").read_text()
    predictor = "linear blend skinning" if task == "pose" else "PCA reconstruction"
    assert f"{predictor} alone (predictor)" in report and "(decoder)" in report and "ms per frame" in report
    assert "Loop subdivision" not in report


def test_each_application_has_its_settings_and_operators_and_pca_has_its_table(applications):
    for application in ("pose", "pca"):
        with h5py.File(applications / application / "operators.h5") as f:
            assert len(f["levels"]) == 6      # its own levels (5 poolings), the scene's has 11
        settings = yaml.safe_load((applications / application / "settings.json").read_text())
        assert settings["network"]["arch"] == "U32 U U32 U16 U3" and "applications" not in settings
    assert not (applications / "operators.h5").exists()      # the upsampling's were not needed
    table = (applications / "pca" / "report.md").read_text()
    assert "| 4 | train |" in table and "| 8 | held-out |" in table and "recovered" in table


def test_a_grid_scene_has_no_pose_input_and_the_applications_are_not_part_of_a_scene(tmp_path):
    run = snakemake(tmp_path, "-n", "results/patch/pose/")
    assert run.returncode != 0
    assert "results/patch/pose/: scene 'patch' has no mannequin, so no pose input" in run.stdout + run.stderr
    plan = snakemake(tmp_path, "-n", "results/pants/")
    assert plan.returncode == 0, tail(plan)
    rules = set(planned_counts(plan))
    assert rules and not rules & {"application_settings", "application_operators", "pose_dataset", "pca_dataset",
                                  "application_train", "application_evaluate", "pca_summary"}
