"""Static topology of the Fig. 4 tree against the seed's Table 1, Table 2 and Sec. II E lists."""

import numpy as np
import pytest

import jaxtree

from helpers import BRANCHES, NEIGHBOURS, TABLE_1, TABLE_2, table


@pytest.fixture(scope="module")
def topo():
    # Sec. II E, item 2: N_1 .. N_10
    return jaxtree.load_scene("fig4").topology


def test_parents_are_the_seeds_input(topo):
    assert topo.parents == (0, 1, 2, 3, 0, 5, 6, 7, 8, 6)


def test_table_1_network_elements(topo):
    np.testing.assert_array_equal(topo.network_elements, table(TABLE_1))


def test_table_2_path_elements(topo):
    np.testing.assert_array_equal(topo.path_elements, table(TABLE_2))


def test_neighbour_sets(topo):
    assert {k: set(v) for k, v in enumerate(topo.neighbours)} == NEIGHBOURS


def test_branch_sets(topo):
    for (k, j), expected in BRANCHES.items():
        assert set(topo.branch(k, j)) == expected, (k, j)
    # 2n branch sets in complementary pairs (Def. 28): B_jk = B - B_kj
    assert len(BRANCHES) == 2 * topo.n
    for (k, j), b in BRANCHES.items():
        assert set(topo.branch(j, k)) == set(range(topo.n + 1)) - b


def test_branch_of_non_neighbour_is_an_error(topo):
    with pytest.raises(ValueError, match="not attached"):
        topo.branch(0, 2)


def test_invalid_parent_is_rejected():
    with pytest.raises(ValueError, match="body 2"):
        jaxtree.Topology([0, 2])


def test_jump_tables_cover_the_depth(topo):
    # depth of the Fig. 4 tree is 5 (bodies 9); ceil(log2(5 + 1)) = 3 pointer-jumping steps
    assert int(topo.depth.max()) == 5
    assert len(topo.jump_tables) == 3


def test_hash_and_equality_are_structural():
    a = jaxtree.Topology([0, 1, 1])
    b = jaxtree.Topology((0, 1, 1))
    assert a == b and hash(a) == hash(b)
    assert a != jaxtree.Topology([0, 0, 1])
