"""The peers' converters for the benchmark scripts: they live in the package
(``jaxtree._src.peers``), which `jaxtree bench` uses too."""

from jaxtree._src.peers import (
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
