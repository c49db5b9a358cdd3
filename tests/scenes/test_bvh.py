"""BVH import: every rotation order, End Sites, position channels, forward kinematics, unit detection, one-line
errors that name the line, gzip-compressed files, a frame-time override, the header alone, and the shared CMU clips
(skipped where ../shared/mocap is absent)."""
import gzip

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bvh_files import Joint, bvh_text, write_bvh
from scenes.bvh import UNITS, BvhHeader, parse_bvh, read_bvh, read_bvh_header, world_transforms
from shared_mocap import MOCAP, manifest

CMU_WALK = MOCAP / "cmu_131_01_walk.bvh"


def elementary(axis: str, degrees: float) -> np.ndarray:
    """Rotation matrix about one axis, written out (independent of scipy's Euler conventions)."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    i, j = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def stick_figure(unit: float) -> list[Joint]:
    """A 1.7 m tall figure (feet on the floor, head End Site at the top) in the given metres per unit."""
    def at(*v):
        return tuple(np.array(v) / unit)
    return [Joint("Hips", -1, at(0, 0.95, 0), has_position=True), Joint("Spine", 0, at(0, 0.1, 0)),
            Joint("Head", 1, at(0, 0.45, 0), end_site=at(0, 0.2, 0)),
            Joint("LeftUpLeg", 0, at(0.1, -0.05, 0)), Joint("LeftLeg", 3, at(0, -0.45, 0)),
            Joint("LeftFoot", 4, at(0, -0.4, 0), end_site=at(0, -0.05, 0.15))]


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_rotation_channels_compose_in_listed_order(tmp_path, order):
    joints = [Joint("Root", -1, (0, 0, 0), order, has_position=True),
              Joint("Tip", 0, (0, 1, 0), "", end_site=(0, 1, 0))]
    angles = [10.0, -20.0, 35.0]
    clip = read_bvh(write_bvh(tmp_path / "one.bvh", joints, np.array([[1.0, 2.0, 3.0, *angles]])), scale=1.0)
    expected = elementary(order[0], angles[0]) @ elementary(order[1], angles[1]) @ elementary(order[2], angles[2])
    np.testing.assert_allclose(Rotation.from_quat(clip.rotations[0, 0]).as_matrix(), expected, atol=1e-12)
    np.testing.assert_allclose(clip.positions[0, 0], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(clip.rotations[0, 1], [0, 0, 0, 1])  # no channels: the identity


def test_hierarchy_end_sites_and_forward_kinematics(tmp_path):
    joints = [Joint("Root", -1, (5, 5, 5), "YXZ", has_position=True), Joint("Arm", 0, (1, 0, 0), "ZYX"),
              Joint("Hand", 1, (1, 0, 0), "XYZ", end_site=(0.5, 0, 0)), Joint("Leg", 0, (0, -1, 0), "ZXY")]
    frames = np.zeros((2, 15))
    frames[1, :9] = [1, 2, 3, 90, 0, 0, 90, 0, 0]   # root moved and turned about y (first of YXZ), arm about z
    clip = read_bvh(write_bvh(tmp_path / "tree.bvh", joints, frames, 0.25), scale=2.0)
    assert clip.names == ("Root", "Arm", "Hand", "Leg") and clip.parents.tolist() == [-1, 0, 1, 0]
    assert clip.name == "tree" and clip.n_frames == 2 and clip.frame_time == 0.25 and clip.duration == 0.25
    assert list(clip.end_sites) == [2]
    np.testing.assert_allclose(clip.end_sites[2], [1.0, 0, 0])          # lengths scaled to metres
    np.testing.assert_allclose(clip.rest_positions(), [[10, 10, 10], [12, 10, 10], [14, 10, 10], [10, 8, 10]])
    np.testing.assert_allclose(clip.positions[:, 0], [[0, 0, 0], [2, 4, 6]])  # channels replace the OFFSET
    _, position = world_transforms(clip)
    # Frame 1: root turned 90° about y (x -> -z), arm a further 90° about z (x -> y): the hand sits above the arm.
    np.testing.assert_allclose(position[1], [[2, 4, 6], [2, 4, 4], [2, 6, 4], [2, 2, 6]], atol=1e-12)


@pytest.mark.parametrize("unit", sorted(UNITS))
def test_unit_detected_from_the_rest_pose_extent(tmp_path, unit):
    joints = stick_figure(UNITS[unit])
    clip = read_bvh(write_bvh(tmp_path / "figure.bvh", joints, np.zeros((2, 3 + 3 * len(joints)))))
    assert clip.unit_scale == UNITS[unit]
    np.testing.assert_allclose(clip.rest_positions()[2], [0, 1.5, 0], atol=1e-9)
    assert read_bvh(tmp_path / "figure.bvh", scale=0.5).unit_scale == 0.5


# Lines: 1 HIERARCHY, 2 ROOT, 4 OFFSET, 5 CHANNELS, 6 JOINT, 17 Frames, 18 Frame Time, 19-20 data.
GOOD = bvh_text([Joint("Hips", -1, (0, 1, 0), "ZXY", has_position=True),
                 Joint("Head", 0, (0, 1, 0), end_site=(0, 1, 0))], np.zeros((2, 9)), 0.01)


@pytest.mark.parametrize("old, new, message", [
    ("\tOFFSET 0 1 0\n\tCHANNELS", "\tOFSET 0 1 0\n\tCHANNELS", ":4: expected 'OFFSET'"),
    ("Zrotation Xrotation Yrotation\n\tJOINT", "Zrotation Xrotation Wrotation\n\tJOINT",
     ":5: unknown channel name (expected Xposition ... Zrotation)"),
    ("Zrotation Xrotation Yrotation\n\tJOINT", "Zrotation Xrotation Xrotation\n\tJOINT",
     ":5: rotation channels must be all three axes once each, got ZXX"),
    ("JOINT Head", "JOINT Hips", ":6: a joint name appears twice (first on line 2)"),
    ("Frames: 2", "Frames: 3", ":18: 'Frames: 3' but 2 data lines follow"),
    ("Frames: 2", "Frames: 2.5", ":17: frame count must be a whole number from 1 to 100,000,000, got 2.5"),
    ("Frame Time: 0.01", "Frame Time: 0", ":18: frame time must be positive, got 0.0"),
    ("\n0 0 0 0 0 0 0 0 0\n", "\n0 0 0 0 0 0 0 0 0 0\n", ":19: expected 9 channel values, got 10"),
    ("0 0 0 0 0 0 0 0 0\n", "0 0 0 0 0 x 0 0 0\n", ":19: a channel value is not a number"),
    ("0 0 0 0 0 0 0 0 0\n0", "0 0 0 0 0 0 0 0 0\nnan", ":20: a channel value is not finite"),
    ("HIERARCHY", "HIERACHY", ":1: expected 'HIERARCHY'"),
])
def test_malformed_file_gives_one_line_naming_the_line(tmp_path, old, new, message):
    assert old in GOOD
    path = tmp_path / "bad.bvh"
    path.write_text(GOOD.replace(old, new, 1))
    with pytest.raises(ValueError) as error:
        read_bvh(path)
    assert str(error.value).startswith(str(path)) and message in str(error.value) and "\n" not in str(error.value)


def test_truncated_file_and_flat_skeleton():
    with pytest.raises(ValueError, match=r"^cut:14: file ends where JOINT, End Site or \} was expected$"):
        parse_bvh(GOOD[:GOOD.index("MOTION")].rstrip().rstrip("}"), source="cut")
    flat = bvh_text([Joint("Hips", -1, (0, 0, 0), has_position=True)], np.zeros((1, 6)), 0.01)
    with pytest.raises(ValueError, match="no extent"):
        parse_bvh(flat)


def test_shared_cmu_walk():
    if not CMU_WALK.exists():
        pytest.skip(f"shared mocap clip not found at {CMU_WALK}")
    clip = read_bvh(CMU_WALK)
    assert clip.n_frames == 994 and abs(1 / clip.frame_time - 120) < 0.01 and len(clip.names) == 31
    assert clip.unit_scale == UNITS["CMU ASF unit"]
    rest = clip.rest_positions()
    assert rest[clip.names.index("Head"), 1] - rest[clip.names.index("LeftAnkle"), 1] > 1.0  # Y up, in metres
    _, position = world_transforms(clip)
    assert np.isfinite(position).all() and 0.85 < position[0, 0, 1] < 1.05   # hips height while standing


def assert_same_clip(a, b):
    assert (a.names, a.n_frames, a.frame_time, a.unit_scale) == (b.names, b.n_frames, b.frame_time, b.unit_scale)
    np.testing.assert_array_equal(a.parents, b.parents)
    for field in ("offsets", "positions", "rotations"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))


def test_gzip_file_reads_as_its_text(tmp_path):
    text = bvh_text(stick_figure(0.01), np.random.default_rng(0).uniform(-30, 30, (5, 21)), 1 / 120)
    plain = tmp_path / "01_01.bvh"
    plain.write_text(text)
    packed = tmp_path / "01_01.bvh.gz"
    packed.write_bytes(gzip.compress(text.encode()))
    clip = read_bvh(packed)
    assert clip.name == "01_01" and clip.n_frames == 5
    assert_same_clip(clip, read_bvh(plain))
    # A byte-order mark, as some Windows exporters write, is not part of the first keyword.
    marked = tmp_path / "marked.bvh"
    marked.write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert_same_clip(read_bvh(marked), clip)


@pytest.mark.parametrize("name, content, message", [
    ("plain.bvh.gz", GOOD.encode(), "not a readable gzip file"),                      # named .gz, not gzip
    ("cut.bvh.gz", gzip.compress(GOOD.encode())[:-12], "not a readable gzip file"),   # stream ends early
    ("latin.bvh", GOOD.replace("Head", "T\xeate").encode("latin-1"), "not UTF-8 text (invalid continuation byte)"),
    ("latin.bvh.gz", gzip.compress(GOOD.replace("Head", "T\xeate").encode("latin-1")), "not UTF-8 text (invalid continuation byte)"),
])
def test_unreadable_bytes_give_one_line_naming_the_file(tmp_path, name, content, message):
    path = tmp_path / name
    path.write_bytes(content)
    for read in (read_bvh, read_bvh_header):
        if read is read_bvh_header and name.startswith("cut"):
            continue   # the header comes before the cut: read_bvh_header never reaches it
        with pytest.raises(ValueError) as error:
            read(path)
        assert str(error.value).startswith(f"{path}: {message}") and "\n" not in str(error.value)


def test_frame_time_given_replaces_the_header(tmp_path):
    path = write_bvh(tmp_path / "salsa.bvh", stick_figure(0.01), np.zeros((121, 21)), 1 / 120)
    header_says = read_bvh(path)
    clip = read_bvh(path, frame_time=1 / 60)     # captured at 60 fps, the header claims 120
    assert header_says.duration == pytest.approx(1.0) and clip.duration == pytest.approx(2.0)
    assert clip.frame_time == 1 / 60
    np.testing.assert_array_equal(clip.rotations, header_says.rotations)
    for wrong in (0.0, -1 / 60, float("nan"), float("inf"), "0.0167", True):
        with pytest.raises(ValueError) as error:
            read_bvh(path, frame_time=wrong)
        assert str(error.value).startswith(f"{path}: the frame time given must be a positive finite number")


@pytest.mark.parametrize("packed", [False, True])
def test_header_alone_equals_the_full_read(tmp_path, packed):
    joints = [Joint("Hips", -1, (0, 95, 0), has_position=True), Joint("Left Up Leg", 0, (10, -5, 0)),
              Joint("LeftLeg", 1, (0, -45, 0), end_site=(0, -45, 0)), Joint("Head", 0, (0, 60, 0), end_site=(0, 20, 0))]
    text = bvh_text(joints, np.random.default_rng(1).uniform(-40, 40, (7, 15)), 0.0333)
    path = tmp_path / ("clip.bvh.gz" if packed else "clip.bvh")
    path.write_bytes(gzip.compress(text.encode()) if packed else text.encode())
    clip = read_bvh(path)
    assert read_bvh_header(path) == BvhHeader(names=clip.names, n_frames=clip.n_frames, frame_time=clip.frame_time)
    assert clip.names == ("Hips", "Left Up Leg", "LeftLeg", "Head") and clip.frame_time == 0.0333
    # It stops at the frame time: motion data that a full read refuses (and, gzipped, a stream cut short far
    # below the header) does not reach it.
    broken = text[:text.index("Frame Time:")] + "Frame Time: 0.0333\n" + "1 2 x\n" * 20000
    path.write_bytes(gzip.compress(broken.encode())[:-6] if packed else broken.encode())
    assert read_bvh_header(path) == BvhHeader(clip.names, clip.n_frames, 0.0333)
    with pytest.raises(ValueError, match="not a readable gzip file" if packed else "'Frames: 7' but 20000"):
        read_bvh(path)


@pytest.mark.parametrize("old, new, message", [
    ("\tOFFSET 0 1 0\n\tCHANNELS", "\tOFSET 0 1 0\n\tCHANNELS", ":4: expected 'OFFSET'"),
    ("JOINT Head", "JOINT Hips", ":6: a joint name appears twice (first on line 2)"),
    ("Frames: 2", "Frames: 2.5", ":17: frame count must be a whole number from 1 to 100,000,000, got 2.5"),
    ("Frame Time: 0.01", "Frame Time: 0", ":18: frame time must be positive, got 0.0"),
    ("Frame Time: 0.01", "Frame Time:", ":19: frame time must be positive, got 0.0"),   # the first value read
    ("MOTION\nFrames: 2\nFrame Time: 0.01\n0 0 0 0 0 0 0 0 0\n0 0 0 0 0 0 0 0 0\n", "MOTION\n",
     ":16: file ends where 'Frames:' was expected"),
])
def test_header_errors_name_the_file_and_line(tmp_path, old, new, message):
    assert old in GOOD
    path = tmp_path / "bad.bvh.gz"
    path.write_bytes(gzip.compress(GOOD.replace(old, new, 1).encode()))
    with pytest.raises(ValueError) as error:
        read_bvh_header(path)
    assert str(error.value) == f"{path}{message}"


@pytest.mark.parametrize("folder", ["cmu", "cmu_rigs"])
def test_shared_library_headers_match_their_manifest(folder):
    rows = manifest(folder)
    assert len(rows) == {"cmu": 167, "cmu_rigs": 4}[folder]
    for row in rows:
        header = read_bvh_header(MOCAP / folder / row["file"])
        assert (header.n_frames, len(header.names), header.names[0]) == (int(row["frames"]), int(row["joints"]),
                                                                         row["root"])
        assert header.frame_time == pytest.approx(float(row["frame_time"]), rel=1e-6)


def test_shared_clip_at_its_true_frame_rate():
    rows = {row["clip"]: row for row in manifest("cmu")}
    salsa = rows["60_10"]      # every header says 120 fps; CMU captured the salsa trials at 60
    assert salsa["cmu_capture_fps"] == "60"
    clip = read_bvh(MOCAP / "cmu" / salsa["file"], frame_time=1 / 60)
    assert clip.n_frames == int(salsa["frames"]) and clip.name == "60_10"
    assert clip.duration == pytest.approx(float(salsa["seconds_corrected"]), abs=0.02)
