"""Static topology of the Fig. 4 tree against the seed's Table 1, Table 2 and Sec. II E lists."""

import numpy as np
import pytest

import jaxtree

# Table 1 of the seed (network elements N_kr, rows k, columns r); row 10 is garbled in the
# OCR and is completed from Def. 26 (see docs/errata.md).
TABLE_1 = """
0 1 1 1 1 5 5 5 5 5 5
0 1 2 2 2 0 0 0 0 0 0
1 1 2 3 3 1 1 1 1 1 1
2 2 2 3 4 2 2 2 2 2 2
3 3 3 3 4 3 3 3 3 3 3
0 0 0 0 0 5 6 6 6 6 6
5 5 5 5 5 5 6 7 7 7 10
6 6 6 6 6 6 6 7 8 8 6
7 7 7 7 7 7 7 7 8 9 7
8 8 8 8 8 8 8 8 8 9 8
6 6 6 6 6 6 6 6 6 6 10
"""

# Table 2 of the seed (path elements epsilon_sk, rows s = 1..10, columns k = 0..10).
TABLE_2 = """
0 1 1 1 1 0 0 0 0 0 0
0 0 1 1 1 0 0 0 0 0 0
0 0 0 1 1 0 0 0 0 0 0
0 0 0 0 1 0 0 0 0 0 0
0 0 0 0 0 1 1 1 1 1 1
0 0 0 0 0 0 1 1 1 1 1
0 0 0 0 0 0 0 1 1 1 0
0 0 0 0 0 0 0 0 1 1 0
0 0 0 0 0 0 0 0 0 1 0
0 0 0 0 0 0 0 0 0 0 1
"""

NEIGHBOURS = {0: {1, 5}, 1: {0, 2}, 2: {1, 3}, 3: {2, 4}, 4: {3}, 5: {0, 6}, 6: {5, 7, 10}, 7: {6, 8},
              8: {7, 9}, 9: {8}, 10: {6}}

# Branch sets printed in Sec. II E (B_76 and B_87 with body 10 restored, see docs/errata.md).
BRANCHES = {
    (0, 1): {1, 2, 3, 4}, (0, 5): {5, 6, 7, 8, 9, 10}, (1, 0): {0, 5, 6, 7, 8, 9, 10}, (1, 2): {2, 3, 4},
    (2, 1): {0, 1, 5, 6, 7, 8, 9, 10}, (2, 3): {3, 4}, (3, 2): {0, 1, 2, 5, 6, 7, 8, 9, 10}, (3, 4): {4},
    (4, 3): {0, 1, 2, 3, 5, 6, 7, 8, 9, 10}, (5, 0): {0, 1, 2, 3, 4}, (5, 6): {6, 7, 8, 9, 10},
    (6, 5): {0, 1, 2, 3, 4, 5}, (6, 7): {7, 8, 9}, (6, 10): {10}, (7, 6): {0, 1, 2, 3, 4, 5, 6, 10},
    (7, 8): {8, 9}, (8, 7): {0, 1, 2, 3, 4, 5, 6, 7, 10}, (8, 9): {9}, (9, 8): {0, 1, 2, 3, 4, 5, 6, 7, 8, 10},
    (10, 6): {0, 1, 2, 3, 4, 5, 6, 7, 8, 9},
}


def _table(text):
    return np.array([[int(x) for x in row.split()] for row in text.strip().splitlines()])


@pytest.fixture(scope="module")
def topo():
    # Sec. II E, item 2: N_1 .. N_10
    return jaxtree.load_scene("fig4").topology


def test_parents_are_the_seeds_input(topo):
    assert topo.parents == (0, 1, 2, 3, 0, 5, 6, 7, 8, 6)


def test_table_1_network_elements(topo):
    np.testing.assert_array_equal(topo.network_elements, _table(TABLE_1))


def test_table_2_path_elements(topo):
    np.testing.assert_array_equal(topo.path_elements, _table(TABLE_2))


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
