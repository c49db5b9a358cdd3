"""The whole precompute: level structure, invariance under translation and uniform scaling, input errors."""
import numpy as np
import pytest

from meshops import build_operators, parse_conv_kind
from meshops_shapes import grid_patch, mesh_of, operators_of


# The last three are issue 41 item 14's: a garment's tables must not depend on where it sits or on its units.
SIMILARITIES = [(3.7, [12.5, -4.0, 7.25]), (1.0, [10.0, -3.0, 7.0]), (100.0, [0.0, 0.0, 0.0]), (0.01, [0.0, 0.0, 0.0])]


@pytest.mark.parametrize("scale, offset", SIMILARITIES)
@pytest.mark.parametrize("name", ["pants", "irregular", "square", "torus", "flag"])
def test_tables_and_pooling_do_not_change_under_translation_and_uniform_scaling(name, scale, offset):
    vertices, faces = mesh_of(name)
    reference = operators_of(name)
    moved = build_operators(vertices * scale + offset, faces)
    assert len(moved) == len(reference)
    for a, b in zip(reference, moved):
        assert np.array_equal(a.faces, b.faces)
        assert np.allclose(a.vertices * scale + offset, b.vertices, rtol=1e-9, atol=1e-12 * scale)
        assert a.fixed_vertex == b.fixed_vertex
        for kind in a.conv:
            assert np.array_equal(a.conv[kind], b.conv[kind]), kind
        if a.coarsening is not None:
            assert np.array_equal(a.coarsening.pool, b.coarsening.pool)


def test_levels_count_pooling_steps_and_only_the_coarsest_has_no_pooling():
    vertices, faces = grid_patch(20, 16)
    levels = build_operators(vertices, faces, ["RC9", "SPD5"], pooling_steps=3)
    assert len(levels) == 4
    assert [level.coarsening is None for level in levels] == [False, False, False, True]
    assert all(set(level.conv) == {"RC9", "SPD5"} for level in levels)
    assert levels[0].conv["RC9"].shape == (320, 9) and levels[3].conv["SPD5"].shape == (len(levels[3].vertices), 5)
    assert np.array_equal(levels[0].vertices, vertices) and np.array_equal(levels[0].faces, faces)
    single = build_operators(vertices, faces, ["EC7"], pooling_steps=0)
    assert len(single) == 1 and single[0].coarsening is None and single[0].conv["EC7"].shape == (320, 7)


def test_separate_pieces_each_get_a_geodesic_source():
    vertices, faces = grid_patch(9, 9)
    both_vertices = np.concatenate([vertices, vertices + [0.0, 2.0, 0.0]])  # a second flag above the first
    both_faces = np.concatenate([faces, faces + len(vertices)])
    level = build_operators(both_vertices, both_faces, ["RC13", "SP13"], pooling_steps=0)[0]
    assert list(level.geodesic_sources) == [81 + 76, 76]  # each piece's top centre
    # Each piece's tables are those of that piece alone, shifted to its vertex ids.
    alone = build_operators(vertices, faces, ["RC13", "SP13"], pooling_steps=0)[0]
    for kind in ("RC13", "SP13"):
        assert np.array_equal(level.conv[kind][:81], alone.conv[kind])
        assert np.array_equal(level.conv[kind][81:], np.where(alone.conv[kind] > 0, alone.conv[kind] + 81, 0))


@pytest.mark.parametrize("name, expected", [("RC13", ("RC", 13)), ("SPD9", ("SPD", 9)), ("SP2", ("SP", 2))])
def test_conv_names_parse(name, expected):
    assert parse_conv_kind(name) == expected


@pytest.mark.parametrize("name", ["RC1", "XC13", "rc13", "RC", "SPD13x", ""])
def test_bad_conv_names_are_refused(name):
    with pytest.raises(ValueError, match="KIND\\+LENGTH"):
        parse_conv_kind(name)


def test_unusable_input_is_refused_before_any_work():
    vertices, faces = grid_patch(4, 4)
    with pytest.raises(ValueError, match="NaN"):
        build_operators(np.where(np.arange(16)[:, None] == 5, np.nan, vertices), faces)
    with pytest.raises(ValueError, match="non-manifold"):
        build_operators(np.r_[vertices, [[0.5, 0.5, 1.0]]], np.r_[faces, [[0, 5, 16]]])  # a third face on 0-5
    with pytest.raises(ValueError, match="pooling steps"):
        build_operators(vertices, faces, pooling_steps=-1)
    with pytest.raises(ValueError, match="named twice"):
        build_operators(vertices, faces, ["RC13", "SP9", "RC13"])
