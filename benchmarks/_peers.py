"""The peers' converters for the benchmark scripts: they live in the package
(``jaxtree.bench.peers``), which `jaxtree bench` uses too."""

from jaxtree.bench.peers import (
    MUJOCO_TINY_INERTIA,
    MUJOCO_TINY_MASS,
    mjcf,
    pinocchio_initial,
    pinocchio_model,
    pinocchio_rhs,
    tree_frames,
)

__all__ = [
    "MUJOCO_TINY_INERTIA",
    "MUJOCO_TINY_MASS",
    "mjcf",
    "pinocchio_initial",
    "pinocchio_model",
    "pinocchio_rhs",
    "tree_frames",
]
