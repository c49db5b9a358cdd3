"""Items 6, 7 and part of 15 of issue 41: BVH files (and configs) from elsewhere. Each hostile file is one
ValueError naming the file and line, found within a second and without reading the file whole: numbers that
overflowed (`Frames: inf`), nesting that overflowed the stack, a file of zeros read whole as one line, 50,000 joints
checked pairwise (21 s), a NaN OFFSET taken for a rest pose without extent, `Frames: nan` without the file's name.
No error quotes the file: a path mistyped as /proc/self/environ once put the environment into the logs."""
from __future__ import annotations

import gzip
import time

import pytest

from pipeline.core.config import load_config
from pipeline.core.errors import PipelineError
from scenes.bvh import read_bvh, read_bvh_header

ROOT = "HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n"
MOTION = "MOTION\nFrames: 1\nFrame Time: 0.01\n"


def _nested(n: int) -> str:
    return ROOT + "".join(f"JOINT j{i}\n{{\nOFFSET 0 1 0\nCHANNELS 0\n" for i in range(n)) + "}\n" * (n + 1)


def _flat(n: int) -> str:
    return ROOT + "".join(f"JOINT j{i}\n{{\nOFFSET 0 1 0\nCHANNELS 0\n}}\n" for i in range(n)) + "}\n"


GOOD = ROOT + "JOINT Head\n{\nOFFSET 0 1.7 0\nCHANNELS 0\n}\n}\n" + MOTION + "0 0 0\n"

HOSTILE = {
    "Frames: inf": (GOOD.replace("Frames: 1", "Frames: inf"), ":13: frame count is not a finite number"),
    "Frames: nan": (GOOD.replace("Frames: 1", "Frames: nan"), ":13: frame count is not a finite number"),
    "Frames: 1e300": (GOOD.replace("Frames: 1", "Frames: 1e300"), ":13: frame count must be a whole number from 1"),
    "frames x joints": (GOOD.replace("Frames: 1", "Frames: 9000000"), "would hold 153,000,000 numbers"),
    "CHANNELS inf": (GOOD.replace("CHANNELS 3", "CHANNELS inf"), ":5: channel count is not a finite number"),
    "CHANNELS 7": (GOOD.replace("CHANNELS 3", "CHANNELS 7"), ":5: channel count must be a whole number from 0 to 6"),
    "NaN OFFSET": (GOOD.replace("OFFSET 0 1.7 0", "OFFSET nan 1.7 0"), ":8: OFFSET value is not a finite number"),
    "Frame Time: inf": (GOOD.replace("Time: 0.01", "Time: inf"), ":14: frame time is not a finite number"),
    "10,000 nested joints": (_nested(10_000) + MOTION + "0 0 0\n", ":4002: more than 1000 joints"),
    "50,000 flat joints": (_flat(50_000) + MOTION + "0 0 0\n", ":5001: more than 1000 joints"),
}


@pytest.mark.parametrize("case", HOSTILE)
@pytest.mark.parametrize("read", [read_bvh, read_bvh_header])
def test_hostile_bvh_is_one_line_naming_file_and_line(tmp_path, case, read):
    text, message = HOSTILE[case]
    path = tmp_path / "hostile.bvh"
    path.write_text(text)
    started = time.perf_counter()
    with pytest.raises(ValueError) as error:
        read(path)
    assert time.perf_counter() - started < 2.0
    assert str(error.value).startswith(f"{path}:") and message in str(error.value), str(error.value)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("packed", [False, True])
def test_a_file_without_newlines_is_not_read_whole(tmp_path, packed):
    """4 GiB of zeros (sparse: no disk used) or a gzip stream of them: refused after the first MiB."""
    path = tmp_path / ("zeros.bvh.gz" if packed else "zeros.bvh")
    if packed:
        path.write_bytes(gzip.compress(bytes(64 << 20), compresslevel=1))
    else:
        with open(path, "wb") as f:
            f.truncate(4 << 30)
    with pytest.raises(ValueError, match=r":1: line longer than 1,048,576 characters"):
        read_bvh(path)


SECRET = "hunter2SECRET"
# Where a word of the file once reached the message: the first keyword, a joint name, a channel, a number, a
# keyword in a joint, gzip's magic bytes.
PLACES = {
    "first word": SECRET + "=x\nPATH=/bin\n",
    "joint name": GOOD.replace("JOINT Head", f"JOINT {SECRET}\n{{\nOFFSET 0 1 0\nCHANNELS 0\n}}\nJOINT {SECRET}"),
    "channel": GOOD.replace("Zrotation", SECRET),
    "number": GOOD.replace("OFFSET 0 1.7 0", f"OFFSET 0 {SECRET} 0"),
    "in a joint": GOOD.replace("JOINT Head", SECRET),
    "keyword": GOOD.replace("OFFSET 0 1.7 0", f"{SECRET} 0 1.7 0"),
}


@pytest.mark.parametrize("place", PLACES)
def test_errors_never_quote_the_file(tmp_path, place):
    path = tmp_path / "clip.bvh"
    path.write_text(PLACES[place])
    for read in (read_bvh, read_bvh_header):
        with pytest.raises(ValueError) as error:
            read(path)
        assert str(error.value).startswith(f"{path}:") and SECRET not in str(error.value), str(error.value)
    packed = tmp_path / "clip.bvh.gz"
    packed.write_bytes(SECRET.encode())
    with pytest.raises(ValueError) as error:
        read_bvh(packed)
    assert "not a readable gzip file" in str(error.value) and "hu" not in str(error.value).replace(str(packed), "")


@pytest.mark.parametrize("text", [f"{SECRET}\n", f"{SECRET}:x:0:0:root:/root:/bin/bash\n", f"- {SECRET}\n"])
def test_a_file_that_is_no_config_is_not_quoted(tmp_path, text):
    path = tmp_path / "config.yaml"
    path.write_text(text)
    with pytest.raises(PipelineError) as error:
        load_config(path)
    assert str(error.value).startswith(f"{path}: not a config") and SECRET not in str(error.value)
