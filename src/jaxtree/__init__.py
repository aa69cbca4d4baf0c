"""jaxtree: differentiable dynamics of hinge-connected rigid-body trees in JAX.

An implementation of P. W. Likins, *Large-Deformation Modal Coordinates for
Nonrigid Vehicle Dynamics*, JPL TR 32-1565 (1972). Importing jaxtree turns on
JAX's float64 mode (``jax_enable_x64``): float64 is the default everywhere;
float32 models (``model.astype(jnp.float32)``) work for GPU batches.
"""

import os as _os

# The Cholesky factorizations of Eq. (1) are small (n + 3 rows); a multi-threaded OpenBLAS
# spins threads against XLA's own and can be 10-100x slower on a busy machine. Respect a
# user's setting; this only takes effect if scipy's OpenBLAS has not been loaded yet.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from .topology import Topology as Topology
from .model import (
    Model as Model,
    State as State,
    Prescription as Prescription,
    SinePrescription as SinePrescription,
    BodyLoads as BodyLoads,
    FunctionLoads as FunctionLoads,
)
from .scene import (
    Body as Body,
    Joint as Joint,
    Free as Free,
    SpringDamper as SpringDamper,
    PrescribedSine as PrescribedSine,
    Prescribed as Prescribed,
    SceneError as SceneError,
    SceneWarning as SceneWarning,
    build_model as build_model,
    validate_model as validate_model,
    load_scene as load_scene,
    scene_from_dict as scene_from_dict,
    scene_to_dict as scene_to_dict,
    save_scene as save_scene,
    scene_path as scene_path,
    list_scenes as list_scenes,
)
from .kinematics import (
    tilde as tilde,
    hinge_rotation as hinge_rotation,
    body_rotations as body_rotations,
    relative_rotations as relative_rotations,
    dcm_rate as dcm_rate,
)
from .dynamics import (
    Accelerations as Accelerations,
    configuration as configuration,
    mass_matrix as mass_matrix,
    rotational_equations as rotational_equations,
    forward_dynamics as forward_dynamics,
    solve_accelerations as solve_accelerations,
    hinge_torques as hinge_torques,
    kinetic_energy as kinetic_energy,
    angular_momentum as angular_momentum,
    mass_center_acceleration as mass_center_acceleration,
    DynamicsError as DynamicsError,
)

__version__ = "0.1.0"
from .linearize import (
    LinearSystem as LinearSystem,
    PartialLinearization as PartialLinearization,
    Structure as Structure,
    linearized_equations as linearized_equations,
    linearize as linearize,
    linearize_vehicle as linearize_vehicle,
    structure as structure,
)
from .modes import (
    Modes as Modes,
    ModalError as ModalError,
    UnstableError as UnstableError,
    DefectiveError as DefectiveError,
    modes as modes,
    first_order as first_order,
)
from .attitude import (
    AbstractAttitude as AbstractAttitude,
    DirectionCosines as DirectionCosines,
    Euler123 as Euler123,
    Quaternion as Quaternion,
)
from .control import (
    AbstractController as AbstractController,
    Controller as Controller,
    HingePD as HingePD,
    HingePID as HingePID,
)
from .loads import (
    PerBodyLoads as PerBodyLoads,
    BodyTorque as BodyTorque,
    GravityGradient as GravityGradient,
    CombinedLoads as CombinedLoads,
    combine_loads as combine_loads,
    thruster_pulse as thruster_pulse,
)
from .simulate import (
    Problem as Problem,
    Solution as Solution,
    SimulationError as SimulationError,
    simulate as simulate,
    check_solution as check_solution,
    hinge_angle_event as hinge_angle_event,
    state_event as state_event,
    default_tolerance as default_tolerance,
)
from .hybrid import (
    HybridModel as HybridModel,
    HybridSolution as HybridSolution,
    hybrid_model as hybrid_model,
    hybrid_rhs as hybrid_rhs,
    hybrid_equations as hybrid_equations,
    simulate_hybrid as simulate_hybrid,
)
from .campaign import (
    monte_carlo as monte_carlo,
)
from . import viewer as viewer
from .diagnostics import (
    Condition as Condition,
    condition as condition,
    SceneReport as SceneReport,
    check_scene as check_scene,
)
from .results import (
    load_result as load_result,
    save_result as save_result,
)
from . import plots as plots
