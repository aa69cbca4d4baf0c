"""Static tree topology: Defs. 4-5 and 26-28 of Likins (1972).

Everything here is integer data fixed by the tree, built once with numpy
outside of any trace. A :class:`Topology` is hashable (it is a static field of
:class:`jaxtree.Model`); the numpy tables it derives are cached on the object
and enter traced code only as constants.

Conventions (the seed's): bodies ``0..n``, body 0 the reference body; hinge
``k`` (``1..n``) joins body ``k`` to its parent ``N_k < k`` (Def. 4).
"""

from __future__ import annotations

import functools

import numpy as np


class Topology:
    """Parents of an n-hinge tree and the tables derived from them.

    **Arguments:**

    - `parents`: ``parents[k-1] = N_k`` for ``k = 1..n`` (Def. 4: ``N_k < k``).
    - `names`: optional body names, ``n + 1`` strings.
    """

    def __init__(self, parents, names=None):
        parents = tuple(int(p) for p in parents)
        for k, p in enumerate(parents, start=1):
            if not 0 <= p < k:
                raise ValueError(f"body {k}: parent must satisfy 0 <= parent < {k} (Def. 4), got {p}")
        n = len(parents)
        if names is None:
            names = tuple(f"b{k}" for k in range(n + 1))
        names = tuple(str(s) for s in names)
        if len(names) != n + 1:
            raise ValueError(f"names: expected {n + 1} names, got {len(names)}")
        self.parents = parents
        self.names = names
        self._hash = hash((parents, names))

    # -- identity: a static field must be hashable and cheap to compare -----------------
    def __hash__(self):
        return self._hash

    def __eq__(self, other):
        if self is other:
            return True
        return isinstance(other, Topology) and self.parents == other.parents and self.names == other.names

    def __reduce__(self):
        # the parents and names alone: the cached tables and the hash (randomized per process for
        # strings) are rebuilt, so equal trees pickle alike (the key of a kept program)
        return (Topology, (self.parents, self.names))

    def __repr__(self):
        return f"Topology(n={self.n}, parents={self.parents})"

    @property
    def n(self) -> int:
        """Number of hinges (Def. 1); there are ``n + 1`` bodies."""
        return len(self.parents)

    # -- Def. 5: neighbour sets -------------------------------------------------------------
    @functools.cached_property
    def children(self) -> tuple[tuple[int, ...], ...]:
        ch = [[] for _ in range(self.n + 1)]
        for k, p in enumerate(self.parents, start=1):
            ch[p].append(k)
        return tuple(tuple(c) for c in ch)

    @functools.cached_property
    def neighbours(self) -> tuple[tuple[int, ...], ...]:
        """``B_k`` of Def. 5, ascending: the bodies attached to body k."""
        out = []
        for k in range(self.n + 1):
            nb = list(self.children[k])
            if k > 0:
                nb.append(self.parents[k - 1])
            out.append(tuple(sorted(nb)))
        return tuple(out)

    # -- Def. 27: path elements -------------------------------------------------------------
    @functools.cached_property
    def path_elements(self) -> np.ndarray:
        """``eps[s-1, k] = epsilon_{sk}`` (Def. 27): 1 iff hinge s lies between b_0 and b_k."""
        n = self.n
        eps = np.zeros((n, n + 1), dtype=np.int8)
        for k in range(1, n + 1):
            eps[:, k] = eps[:, self.parents[k - 1]]
            eps[k - 1, k] = 1
        eps.setflags(write=False)
        return eps

    @functools.cached_property
    def depth(self) -> np.ndarray:
        """Number of hinges between b_0 and b_k."""
        return self.path_elements.sum(axis=0).astype(np.int64)

    # -- Def. 26: network elements ------------------------------------------------------------
    @functools.cached_property
    def network_elements(self) -> np.ndarray:
        """``N[k, r] = N_kr`` (Def. 26): the neighbour of b_k on the path toward b_r; ``N_kk = k``."""
        n = self.n
        eps = self.path_elements
        N = np.empty((n + 1, n + 1), dtype=np.int64)
        for k in range(n + 1):
            for r in range(n + 1):
                if r == k:
                    N[k, r] = k
                    continue
                # a child c of k leads to r iff hinge c is on the path to r; otherwise the parent does.
                via = [c for c in self.children[k] if eps[c - 1, r]]
                N[k, r] = via[0] if via else self.parents[k - 1]
        N.setflags(write=False)
        return N

    # -- Def. 28: branch sets --------------------------------------------------------------------
    def branch(self, k: int, j: int) -> tuple[int, ...]:
        """``B_kj`` (Def. 28): bodies on the branch attached to b_k that begins with b_j."""
        if j not in self.neighbours[k]:
            raise ValueError(f"branch B_{k},{j}: body {j} is not attached to body {k}")
        row = self.network_elements[k]
        return tuple(int(r) for r in range(self.n + 1) if r != k and row[r] == j)

    # -- index tables for vectorized sums (used at trace time) --------------------------------
    @functools.cached_property
    def descendants(self) -> np.ndarray:
        """``E[s, k] = 1`` iff body k is outboard of hinge s or is s (``epsilon_{sk}``); row 0 is all ones.

        Sums over outboard sets are products with this static matrix (see
        :func:`jaxtree._src.equations.kinematics.subtree_sum`).
        """
        E = np.concatenate([np.ones((1, self.n + 1), np.int8), self.path_elements], 0)
        E.setflags(write=False)
        return E

    @functools.cached_property
    def jump_tables(self) -> tuple[np.ndarray, ...]:
        """Pointer-jumping tables: ``tables[i][k]`` is the ``2**i``-th ancestor of body k, or ``n + 1``.

        Index ``n + 1`` stands for "no such body"; arrays that use these tables carry a
        zero (or identity) row there. There are ``ceil(log2(max depth + 1))`` tables.
        """
        n = self.n
        none = n + 1
        first = np.array((none,) + self.parents + (none,), dtype=np.int32)
        tables = []
        anc = first
        reach = 1
        max_depth = int(self.depth.max()) if n else 0
        while reach <= max_depth:
            tables.append(anc)
            anc = anc[anc]
            reach *= 2
        return tuple(tables)
