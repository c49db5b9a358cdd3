"""The architecture grammar, the paper's Table 3 parameter counts, and the summary CLI."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from model import summary
from model.architecture import ArchitectureError, parse_architecture, parse_conv
from model.networks import EncoderDecoder, NetworkSpec, build_network

PAPER_ARCH = "D62 D124 D248 D D248 D_3 D248"


@pytest.mark.parametrize("conv, width, expected", [
    ("RC13", 1.0, 7_902_829),   # paper Table 3
    ("RC9", 1.0, 5_471_897),
    ("RC9", 0.5, 1_371_757),
    ("RC9", 0.25, 346_265),
])
@pytest.mark.parametrize("pool", ["avg", "max"])
def test_encoder_decoder_matches_paper_parameter_counts(conv, width, expected, pool):
    net = build_network(NetworkSpec(PAPER_ARCH, conv, pool, width))
    assert net.parameter_count() == expected
    assert sum(p.numel() for p in net.parameters()) == expected      # nothing learnable hides outside convs


def test_parameter_count_formula_by_hand():
    # D^4 D D^6 with L = 5: encoder 3->4, 4->6; decoder U^4: 6->4, 8->4; head 4->3, 3->3.
    convs = [(3, 4), (4, 6), (6, 4), (8, 4), (4, 3), (3, 3)]
    expected = sum(5 * a * b + b for a, b in convs)
    net = EncoderDecoder(parse_architecture("D4 D D6", "D"), 5)
    assert net.parameter_count() == expected
    assert net.n_levels == 3


@pytest.mark.parametrize("text, blocks", [
    ("D62 D D_3 D248", (62, None, None, None, None, 248)),
    ("D^{62}_{2} D^8", (62, 62, 8)),
    ("D62_2 D^8_1", (62, 62, 8)),
    ("U208 U U3", (208, None, 3)),
])
def test_grammar_expands_tokens(text, blocks):
    arch = parse_architecture(text, text[0])
    assert arch.blocks == blocks
    assert parse_architecture(str(arch), text[0]) == arch             # canonical form round-trips


@pytest.mark.parametrize("text, letter, message", [
    ("", "D", "empty"),
    ("D62 X5 D8", "D", "token 2 'X5'"),
    ("D62 D^", "D", "token 2"),
    ("D62 U8", "D", "D tokens only"),
    ("D0 D8", "D", "must be >= 1"),
    ("D62_0", "D", "must be >= 1"),
])
def test_grammar_rejects_bad_strings(text, letter, message):
    with pytest.raises(ArchitectureError, match=message):
        parse_architecture(text, letter)


def test_network_rejects_unbuildable_architectures():
    with pytest.raises(ArchitectureError, match="ends with a plain pooling"):
        build_network(NetworkSpec("D62 D124 D"))
    with pytest.raises(ArchitectureError, match="end with the output block U\\^3"):
        build_network(NetworkSpec("U8 U U8", coarse_vertices=4))
    with pytest.raises(ArchitectureError, match="pooling must be one of"):
        build_network(NetworkSpec("D8", pool="median"))
    with pytest.raises(ArchitectureError, match="convolution 'XY13'"):
        build_network(NetworkSpec("D8", conv="XY13"))
    with pytest.raises(ArchitectureError, match="width multiplier"):
        build_network(NetworkSpec("D8", width=0))


def test_width_rounds_up_to_even_and_keeps_output():
    assert parse_architecture("D62 D D124 D248", "D").scaled(0.5).blocks == (32, None, 62, 124)
    assert parse_architecture("D62 D D124 D248", "D").scaled(0.25).blocks == (16, None, 32, 62)
    assert parse_architecture("D3 D5", "D").scaled(1.0).blocks == (3, 5)
    assert parse_architecture("U208 U104 U3", "U").scaled(0.5, keep_last=True).blocks == (104, 52, 3)


def test_parse_conv():
    assert parse_conv("RC13") == ("RC", 13)
    assert parse_conv("SPD9") == ("SPD", 9)
    with pytest.raises(ArchitectureError):
        parse_conv("RC")


def test_summary_prints_table_and_total(capsys):
    summary.main([PAPER_ARCH, "--conv", "RC9", "--width", "0.5", "--pool", "max"])
    out = capsys.readouterr().out
    assert "learnable parameters: 1,371,757" in out
    assert "max pool -> level 1" in out and "concat skip" in out
    # 5 DownConvs, 4 UpConvs of two convs each (the deepest DownConv has no partner), 2 head convs.
    assert out.count("conv L=9") == 15


def test_summary_reports_bad_architecture(capsys):
    with pytest.raises(SystemExit) as exit_info:
        summary.main(["D62 Q"])
    assert exit_info.value.code == 2
    assert "token 2 'Q'" in capsys.readouterr().err


def test_summary_of_a_decoder_reads_the_coarsest_vertex_count(grid, tmp_path, capsys):
    _, _, mesh = grid
    path = tmp_path / "operators.h5"
    with h5py.File(path, "w") as f:
        for level, count in enumerate(mesh.vertex_counts):
            f[f"levels/{level}/vertices"] = np.zeros((count, 3), dtype=np.float32)
    summary.main(["U8 U U3", "--conv", "RC7", "--in-channels", "5", "--operators", str(path)])
    out = capsys.readouterr().out
    coarse = mesh.vertex_counts[3]
    expected = 5 * coarse * 8 + coarse * 8 + sum(7 * a * b + b for a, b in [(8, 8), (8, 8), (8, 3), (3, 3)])
    assert f"learnable parameters: {expected:,}" in out and f"5 -> {coarse} x 8" in out
    with pytest.raises(SystemExit):
        summary.main(["U8 U U U U U3", "--conv", "RC7", "--operators", str(path)])
    assert "needs 7 mesh levels" in capsys.readouterr().err
