"""The dataset's test split of contiguous windows (issue 35: an honest test, no trained frame near a tested one)
beside the random one: the blocks, the guard by frame time and by a library file's motion (checked against
references computed here from what dataset.h5 records), the share, the seed, sequences shorter than a block,
the notes and errors, what the file records; and the random split as it always was."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from library_sheets import FRAME_TIME, window, write_sheet_sequence
from pipeline import dataset
from pipeline.artifacts.dataset import load_dataset
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import config_of
from pipeline.dataset import guard_frames, near_test, split_windows
from stage_inputs import stage

FRAMES = 40                 # per sequence: 4 s at the sheet's 0.1 s per frame
WINDOW, GUARD = 0.8, 0.3    # seconds: blocks of 8 frames, guards of 3


def runs_of(ids: np.ndarray, sequence: np.ndarray) -> list[np.ndarray]:
    """Sorted frame ids cut into runs of consecutive frames of one sequence."""
    cuts = (np.diff(ids) != 1) | (np.diff(sequence[ids]) != 0)
    return np.split(ids, np.flatnonzero(cuts) + 1) if len(ids) else []


def violations(keys: np.ndarray, times: np.ndarray, test: np.ndarray, train: np.ndarray, reach: float) -> int:
    """Pairs of a test and a train frame of one timeline (key >= 0) at most `reach` apart, counted pair by pair."""
    same = (keys[test][:, None] == keys[train][None, :]) & (keys[test][:, None] >= 0)
    return int(np.sum(same & (np.abs(times[test][:, None] - times[train][None, :]) <= reach)))


# -- the split on its own, against brute-force references --------------------------------------------------------

def synthetic(seed: int) -> tuple[np.ndarray, list]:
    """Sequences of random lengths, every other one a window of one of two takes lying end to end in its take's
    motion: the frames' sequence ids and their two clocks."""
    rng = np.random.default_rng(seed)
    lengths = rng.integers(5, 60, size=8)
    sequence = np.repeat(np.arange(8), lengths)
    run_time = np.concatenate([np.arange(n) for n in lengths])
    take = np.where(sequence % 2 == 0, sequence % 4 // 2, -1)
    starts = {k: sum(lengths[j] for j in range(k) if j % 4 == k % 4) for k in range(8)}
    motion_time = run_time + np.array([starts[k] for k in sequence])
    return sequence, [(sequence, run_time), (take, motion_time)]


@pytest.mark.parametrize("seed", range(6))
def test_no_train_frame_lies_within_the_guard_of_a_test_frame_on_any_clock(seed):
    sequence, clocks = synthetic(seed)
    train, test, guard = split_windows(sequence, clocks, 0.15, 10, 4, seed)
    assert sum(violations(k, t, test, train, 4) for k, t in clocks) == 0
    # ... and the guard takes no frame more: each lies within reach of a test frame on some clock
    for frame in guard:
        assert any(violations(k, t, test, np.array([frame]), 4) for k, t in clocks)
    assert np.array_equal(np.sort(np.concatenate([train, test, guard])), np.arange(len(sequence)))


def slots_of(sequence: np.ndarray, block: int) -> list[np.ndarray]:
    """Each sequence's frames cut into the fewest slots of at most `block` frames, the longer first."""
    return [part for k in np.unique(sequence) for ids in [np.flatnonzero(sequence == k)]
            for part in np.array_split(ids, -(-len(ids) // block))]


@pytest.mark.parametrize("seed", range(6))
def test_test_frames_are_whole_slots_but_one_contiguous_part_and_make_the_share(seed):
    sequence, clocks = synthetic(seed)
    _, test, _ = split_windows(sequence, clocks, 0.15, 10, 4, seed)
    assert len(test) == round(0.15 * len(sequence))
    tested = [np.isin(slot, test) for slot in slots_of(sequence, 10)]
    partly = [t for t in tested if 0 < t.sum() < len(t)]
    assert len(partly) <= 1 and all(len(runs_of(np.flatnonzero(t), np.zeros(len(t), int))) == 1 for t in partly)


def test_the_split_is_seeded():
    sequence, clocks = synthetic(0)
    first, again = (split_windows(sequence, clocks, 0.15, 10, 4, 3) for _ in range(2))
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    others = [split_windows(sequence, clocks, 0.15, 10, 4, seed)[1] for seed in range(4, 8)]
    assert any(not np.array_equal(first[1], test) for test in others)


def test_a_block_at_the_end_of_a_window_guards_the_start_of_the_next_window_of_its_take():
    # window 1 follows window 0 in its take's motion, window 2 is another take; a seed that tests window 0 whole
    sequence = np.repeat([0, 1, 2], [10, 9, 9])
    run_time = np.concatenate([np.arange(10), np.arange(9), np.arange(9)])
    take = np.repeat([0, 0, 1], [10, 9, 9])
    motion = np.concatenate([np.arange(10), 10 + np.arange(9), np.arange(9)])
    splits = (split_windows(sequence, [(sequence, run_time), (take, motion)], 10 / 28, 10, 4, seed)
              for seed in range(50))
    train, test, guard = next(split for split in splits if np.array_equal(split[1], np.arange(10)))
    np.testing.assert_array_equal(guard, np.arange(10, 14))          # motion frames 10-13: within 4 of frame 9
    np.testing.assert_array_equal(train, np.arange(14, 28))


def test_near_test_measures_on_each_timeline_alone():
    keys = np.array([0, 0, 0, 1, 1, -1])
    times = np.array([0, 5, 9, 5, 9, 5])
    is_test = np.array([False, True, False, False, False, False])
    np.testing.assert_array_equal(near_test(keys, times, is_test, 4), [False, True, True, False, False, False])


def test_sequences_shorter_than_a_block_are_slots_of_their_own_and_a_guard_over_all_is_one_error():
    sequence = np.repeat([0, 1, 2], [4, 9, 3])
    clocks = [(sequence, np.r_[np.arange(4), np.arange(9), np.arange(3)])]
    tests = [split_windows(sequence, clocks, 0.25, 10, 0, seed)[1] for seed in range(8)]
    assert any(np.array_equal(test, np.arange(4)) for test in tests)       # the first sequence tested whole
    with pytest.raises(PipelineError, match="every training frame is test or within dataset.guard"):
        split_windows(np.zeros(12, np.int64), [(np.zeros(12, np.int64), np.arange(12))], 0.1, 10, 12, 0)


# -- the stage ---------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """A motion program, two windows of one take end to end (train), a window of another subject's take (train),
    a window shorter than a block, and a held-out subject's window."""
    root = tmp_path_factory.mktemp("library")
    seconds = FRAMES * FRAME_TIME
    folders = [
        write_sheet_sequence(root, "train_000", "train", None, FRAMES),
        write_sheet_sequence(root, "train_001-01_w00", "train", window("001/01.bvh", "1", "walk", 0.0, seconds),
                             FRAMES, 1.2),
        write_sheet_sequence(root, "train_001-01_w01", "train",
                             window("001/01.bvh", "1", "walk", seconds, 2 * seconds), FRAMES, 0.8),
        write_sheet_sequence(root, "train_002-01_w00", "train", window("002/01.bvh", "2", "run", 0.0, seconds),
                             FRAMES, 1.5),
        write_sheet_sequence(root, "train_002-02_w00", "train", window("002/02.bvh", "2", "run", 0.0, 0.5), 5),
        write_sheet_sequence(root, "held_out_003-01_w00", "held_out",
                             window("003/01.bvh", "3", "walk", 0.0, seconds), FRAMES, 0.5),
    ]
    return root, folders


def make(root, folders, out, *flags) -> None:
    stage(dataset.main, root / "subdiv.h5", out, *folders, *flags, "--quiet")


def windows_dataset(library, out, seed: int):
    root, folders = library
    make(root, folders, out, "--test-split", "windows", "--test-window", WINDOW, "--guard", GUARD, "--seed", seed,
         "--test-fraction", 0.15)
    return out


@pytest.mark.parametrize("seed", range(3))
def test_no_frame_trained_on_lies_within_the_guard_of_a_test_frame_by_frame_time(library, tmp_path, seed):
    out = windows_dataset(library, tmp_path / "windows.h5", seed)
    data = load_dataset(out)
    with h5py.File(out) as f:
        frame, span = f["sequence_frame"][()], f["sequences/library_span"][()]
        files = [name.decode() for name in f["sequences/library_file"][()]]
    time = frame * data.context.frame_time                         # seconds in its sequence's run
    assert violations(data.sequence, time, data.test, data.train, GUARD + 1e-9) == 0
    # in a take's motion too: the sheet's windows start their clip at their first frame
    take = np.array([sorted(set(files)).index(files[k]) if files[k] else -1 for k in data.sequence])
    motion = span[data.sequence, 0] + time
    assert violations(take, motion, data.test, data.train, GUARD + 1e-9) == 0
    # the guard frames are the ones that near a test frame
    assert all(violations(data.sequence, time, data.test, np.array([g]), GUARD + 1e-9)
               or violations(take, motion, data.test, np.array([g]), GUARD + 1e-9) for g in data.guard)
    seen = np.flatnonzero(data.sequence != 5)                          # the held-out window is sequence 5
    assert len(data.test) == round(0.15 * len(seen))
    assert len(runs_of(data.test, data.sequence)) <= -(-len(data.test) // 8)
    assert np.array_equal(np.sort(np.concatenate([data.train, data.test, data.guard])), seen)
    np.testing.assert_array_equal(data.held_out, np.flatnonzero(data.sequence == 5))


def test_a_test_block_guards_the_frames_of_the_neighbouring_window_of_its_take(library, tmp_path):
    """Windows 0 and 1 of take 001/01 lie end to end in its motion: over a few seeds, a test block near where
    they meet makes frames of the other window guard, though none of that window is test."""
    guarded_alone = []
    for seed in range(6):
        data = load_dataset(windows_dataset(library, tmp_path / f"seed_{seed}.h5", seed))
        tested = set(data.sequence[data.test].tolist())
        guarded_alone += [k for k in set(data.sequence[data.guard].tolist()) - tested]
    assert set(guarded_alone) & {1, 2}


def test_the_dataset_records_its_split_and_says_what_it_took(library, tmp_path, capsys):
    out = windows_dataset(library, tmp_path / "windows.h5", 0)
    notes = capsys.readouterr().err
    data = load_dataset(out)
    assert (data.test_split.kind, data.test_split.window, data.test_split.guard) == ("windows", WINDOW, GUARD)
    assert f"test split 'windows': {len(data.test)} test frames in " in notes
    assert f"(blocks of up to 8 frames, 0.8 s); {len(data.guard)} guard frames" in notes and len(data.guard) > 0
    with h5py.File(out) as f:
        assert f.attrs["test_split"] == "windows" and f.attrs["test_window"] == WINDOW and f.attrs["guard"] == GUARD
        np.testing.assert_array_equal(f["split/guard"][()], data.guard)
        assert "guard" in f["split"].attrs["meaning"]
        assert {k: config_of(f)[k] for k in ("test_split", "test_window", "guard")} == \
               {"test_split": "windows", "test_window": WINDOW, "guard": GUARD}
    # same seed, same split
    again = load_dataset(windows_dataset(library, tmp_path / "again.h5", 0))
    assert np.array_equal(again.test, data.test) and np.array_equal(again.guard, data.guard)


def test_the_random_split_draws_the_frames_it_always_drew(library, tmp_path):
    root, folders = library
    make(root, folders, tmp_path / "default.h5", "--seed", 4)
    make(root, folders, tmp_path / "random.h5", "--seed", 4, "--test-split", "random", "--guard", 5)
    default, random = load_dataset(tmp_path / "default.h5"), load_dataset(tmp_path / "random.h5")
    seen = np.flatnonzero(default.sequence != 5)
    order = np.random.default_rng(4).permutation(len(seen))          # the split as it was written before windows
    n_test = round(0.1 * len(seen))
    for data in (default, random):
        np.testing.assert_array_equal(data.test, seen[np.sort(order[:n_test])])
        np.testing.assert_array_equal(data.train, seen[np.sort(order[n_test:])])
        assert data.test_split.kind == "random" and len(data.guard) == 0
    with h5py.File(tmp_path / "random.h5") as f:
        assert f.attrs["test_split"] == "random" and "split/guard" not in f and "test_window" not in f.attrs
        assert set(config_of(f)) == {"subdiv", "sequences", "frame", "test_fraction", "seed"}


def test_a_test_window_longer_than_every_sequence_tests_whole_sequences(library, tmp_path, capsys):
    root, folders = library
    make(root, folders, tmp_path / "whole.h5", "--test-split", "windows", "--test-window", 10, "--guard", 0,
         "--test-fraction", 0.3, "--seed", 2)
    data = load_dataset(tmp_path / "whole.h5")
    tested = np.unique(data.sequence[data.test])
    whole = [k for k in tested if np.isin(np.flatnonzero(data.sequence == k), data.test).all()]
    assert len(whole) >= len(tested) - 1 and len(data.guard) == 0
    notes = capsys.readouterr().err                # a sequence tested whole is said to train nothing
    assert all(f"sequence {folders[k].name}: all " in notes for k in range(5) if k not in data.sequence[data.train])


def test_bad_window_or_guard_settings_are_one_error(library, tmp_path, capsys):
    root, folders = library
    with pytest.raises(SystemExit):
        make(root, folders[:1], tmp_path / "d.h5", "--test-split", "windows", "--guard", 100)
    assert "every training frame is test or within dataset.guard (--guard)" in capsys.readouterr().err
    for flags, message in ((("--test-window", 0), "--test-window must be > 0"), (("--guard", -1), "--guard >= 0")):
        with pytest.raises(SystemExit):
            make(root, folders, tmp_path / "d.h5", "--test-split", "windows", *flags)
        assert message in capsys.readouterr().err
    assert not (tmp_path / "d.h5").exists()


def test_a_guard_overlapping_a_split_is_refused_on_reading(library, tmp_path):
    out = windows_dataset(library, tmp_path / "windows.h5", 1)
    with h5py.File(out, "r+") as f:
        guard = f["split/guard"][()]
        del f["split/guard"]
        f["split/guard"] = np.r_[guard, f["split/train"][0]]
    with pytest.raises(PipelineError, match="must be disjoint frame ids"):
        load_dataset(out)


@pytest.mark.parametrize("damage, message", [
    (lambda f: f.attrs.__setitem__("test_split", "blocks"), "attr 'test_split' is 'blocks', not 'random' or"),
    (lambda f: f.attrs.__delitem__("guard"), "a 'windows' test split needs attrs 'test_window' and 'guard'"),
    (lambda f: f.attrs.__setitem__("test_window", np.inf), "must be finite seconds"),
    (lambda f: f.__delitem__("split/guard"), "missing dataset 'split/guard'"),
])
def test_a_damaged_record_of_the_split_is_one_error(library, tmp_path, damage, message):
    out = windows_dataset(library, tmp_path / "windows.h5", 2)
    with h5py.File(out, "r+") as f:
        damage(f)
    with pytest.raises(PipelineError, match=message):
        load_dataset(out)


def test_a_guard_of_whole_frames_counts_them_all_whatever_the_stored_time_step():
    assert guard_frames(1.0, 0.0166666667) == guard_frames(1.0, 1 / 60) == 60     # the runs' dt, as stored
    assert guard_frames(0.3, 0.1) == 3 and guard_frames(0.35, 0.1) == 3 and guard_frames(0.0, 0.1) == 0
