"""scenes.library and the library's sequences (scenes.sequences): a folder of BVH files becomes windows, each a
sequence named after its file, with subjects held out whole, true frame rates over wrong headers, and a file that
cannot be read planned anyway (its scene stage drops it)."""
import gzip
from pathlib import Path

import pytest

from scenes.library import find_window, library_clips, slug, subject_id, windows
from scenes.sequences import (HELD_OUT, TRAIN, is_window_name, sequence_bvh_files, sequence_names, sequence_role,
                              sequence_shards, window_key)


def bvh_text(n_frames: int, frame_time: float) -> str:
    """A two-joint BVH of `n_frames` frames (what planning reads is its header)."""
    rows = "\n".join("0 90 0 0 0 0 0 0 0" for _ in range(n_frames))
    return ("HIERARCHY\nROOT hip\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
            "Yrotation\n JOINT abdomen\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  End Site\n"
            "  {\n   OFFSET 0 10 0\n  }\n }\n}\n"
            f"MOTION\nFrames: {n_frames}\nFrame Time: {frame_time}\n{rows}\n")


@pytest.fixture
def folder(tmp_path):
    """Subjects 001 (two clips, gzip) and 016 (one clip, plain), a clip claiming 120 fps that is 60, a broken
    file, and a manifest."""
    root = tmp_path / "library"
    (root / "001").mkdir(parents=True)
    (root / "016").mkdir()
    # 20 s and 3 s of motion at 120 fps after a T-pose and the converter's blend out of it (REST_LEAD_FRAMES)
    for name, frames in (("001/01_01.bvh.gz", 2409), ("001/01_02.bvh.gz", 369)):
        (root / name).write_bytes(gzip.compress(bvh_text(frames, 1 / 120).encode()))
    (root / "016/16_01.bvh").write_text(bvh_text(1209, 1 / 120))                       # 10 s at 120, 20 s at 60
    (root / "016/16_02.bvh.gz").write_bytes(b"not gzip at all")
    (root / "MANIFEST.tsv").write_text(
        "file\tsubject\tcategory\tdescription\tcapture_fps\n"
        "001/01_01.bvh.gz\t1\twalk\twalk around\t120\n001/01_02.bvh.gz\t1\tjump_hop\thop\t120\n"
        "016/16_01.bvh\t16\tdance\tsalsa\t60\n")
    return root


def library(folder: Path, **overrides) -> dict:
    return {"dir": str(folder), "manifest": "MANIFEST.tsv", "fps_column": "capture_fps", "frame_rates": {},
            "window": 8.0, "hold_frames": 100, **overrides}


def garment_settings(folder: Path, held: list[str] = (), **selection) -> dict:
    return {"mesh": {"generator": "garment"}, "sequences": 2, "shard": 2,
            "dataset": {"split": "held_out" if held else "random"},
            "drivers": {"mannequin": {"clips": ["dance"], "test_clips": [], "library": library(folder)}},
            "library_windows": {"include": ["*"], "exclude": [], "max_clips": 0, "held_out_subjects": list(held),
                                **selection}}


def test_every_file_is_planned_from_its_header_with_the_manifests_subject_category_and_true_rate(folder):
    clips = {clip.file: clip for clip in library_clips(library(folder))}
    assert list(clips) == ["001/01_01.bvh.gz", "001/01_02.bvh.gz", "016/16_01.bvh", "016/16_02.bvh.gz"]
    walk = clips["001/01_01.bvh.gz"]
    assert (walk.subject, walk.category, walk.description, walk.n_frames) == ("1", "walk", "walk around", 2409)
    assert walk.frame_time == pytest.approx(1 / 120) and walk.motion_seconds == pytest.approx(20.0)
    salsa = clips["016/16_01.bvh"]
    assert salsa.frame_time == pytest.approx(1 / 60) and salsa.motion_seconds == pytest.approx(20.0)   # not 10
    broken = clips["016/16_02.bvh.gz"]
    assert broken.problem.startswith(str(folder / "016/16_02.bvh.gz")) and broken.frame_time is None
    assert broken.subject == "16"        # not in the manifest: its folder, the same subject as the manifest's "16"
    # A config rate beats the manifest's, which beats the header's.
    assert library_clips(library(folder, frame_rates={"016/*": 30}))[2].frame_time == pytest.approx(1 / 30)
    assert library_clips(library(folder, fps_column=None))[2].frame_time == pytest.approx(1 / 120)


def test_windows_cut_the_whole_motion_into_the_fewest_equal_windows(folder):
    clips = library_clips(library(folder))
    spans = [(w.start, w.end) for w in windows(clips[0], 8.0)]          # 20 s: three of 6.67 s, nothing left out
    assert spans == [pytest.approx((0.0, 20 / 3)), pytest.approx((20 / 3, 40 / 3)), pytest.approx((40 / 3, 20.0))]
    assert [(w.start, w.end) for w in windows(clips[0], 5.0)] == [(0, 5), (5, 10), (10, 15), (15, 20)]
    short = windows(clips[1], 8.0)
    assert len(short) == 1 and short[0].end == pytest.approx(3.0)
    assert [w.key for w in windows(clips[0], 8.0)] == ["001-01-01_w00", "001-01-01_w01", "001-01-01_w02"]
    assert windows(clips[3], 8.0)[0].end == 0.0           # unreadable: one empty window, dropped downstream


def test_sequences_follow_the_programs_and_hold_whole_subjects_out(folder):
    names = sequence_names(garment_settings(folder, held=["016"]))
    assert names == ["train_000", "train_001", "train_001-01-01_w00", "train_001-01-01_w01", "train_001-01-01_w02",
                     "train_001-01-02_w00", "held_out_016-16-01_w00", "held_out_016-16-01_w01",
                     "held_out_016-16-01_w02", "held_out_016-16-02_w00"]
    assert [sequence_role(n) for n in names] == [TRAIN] * 6 + [HELD_OUT] * 4
    assert [is_window_name(n) for n in names] == [False, False] + [True] * 8
    assert window_key(names[-1]) == "016-16-02_w00"
    # Training and held-out sequences shard apart, the programs in order, the windows by length: the 3 s hop
    # before the walk's 6.7 s windows, the unreadable file's empty window before the salsa's.
    by_length = names[:2] + names[5:6] + names[2:5] + names[9:] + names[6:9]
    assert sequence_shards(garment_settings(folder, held=["16"])) == [by_length[:2], by_length[2:4], by_length[4:6],
                                                                      by_length[6:8], by_length[8:]]
    # Selection: globs and the first max_clips files; without a held-out subject everything trains.
    assert sequence_names(garment_settings(folder, include=["016/*"], exclude=["*.gz"])) == [
        "train_000", "train_001", "train_016-16-01_w00", "train_016-16-01_w01", "train_016-16-01_w02"]
    assert len(sequence_names(garment_settings(folder, max_clips=1))) == 2 + 3


def test_a_window_is_found_again_by_its_name_and_names_its_file(folder):
    settings = garment_settings(folder)
    window = find_window(library(folder), "001-01-01_w01")
    assert (window.clip.file, window.start, window.end) == ("001/01_01.bvh.gz", pytest.approx(20 / 3),
                                                            pytest.approx(40 / 3))
    assert window.describe() == {"file": "001/01_01.bvh.gz", "subject": "1", "category": "walk",
                                 "description": "walk around", "start": pytest.approx(20 / 3),
                                 "end": pytest.approx(40 / 3), "frame_time": pytest.approx(1 / 120)}
    assert sequence_bvh_files(settings, "train_001-01-01_w01") == [str(folder / "001/01_01.bvh.gz")]
    with pytest.raises(ValueError, match="has 3 window"):
        find_window(library(folder), "001-01-01_w03")
    with pytest.raises(ValueError, match="no BVH file whose name gives 'nobody'"):
        find_window(library(folder), "nobody_w00")


def test_names_and_subjects_are_normalised():
    assert slug("001/01_01.bvh.gz") == "001-01-01" and slug("a b/c.d.BVH") == "a-b-c-d"
    assert subject_id("016") == subject_id("16") == "16" and subject_id(" salsa ") == "salsa"


def test_a_missing_folder_or_manifest_is_the_configs_mistake(folder, tmp_path):
    with pytest.raises(ValueError, match="motion library folder does not exist"):
        library_clips(library(tmp_path / "nowhere"))
    with pytest.raises(ValueError, match="cannot read the library's manifest"):
        library_clips(library(folder, manifest="NOPE.tsv"))
    (folder / "BAD.tsv").write_text("path\tsubject\nx\t1\n")
    with pytest.raises(ValueError, match="no 'file' column"):
        library_clips(library(folder, manifest="BAD.tsv"))
