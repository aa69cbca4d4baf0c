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

from ._src.topology import Topology as Topology
from ._src.model import (
    Model as Model,
    State as State,
    Prescription as Prescription,
    SinePrescription as SinePrescription,
    BodyLoads as BodyLoads,
    FunctionLoads as FunctionLoads,
)
from ._src.scene import (
    Body as Body,
    Joint as Joint,
    Free as Free,
    SpringDamper as SpringDamper,
    PrescribedSine as PrescribedSine,
    Prescribed as Prescribed,
    build_model as build_model,
    validate_model as validate_model,
    load_scene as load_scene,
    scene_from_dict as scene_from_dict,
    scene_to_dict as scene_to_dict,
    save_scene as save_scene,
    scene_path as scene_path,
    list_scenes as list_scenes,
)
from ._src.kinematics import (
    tilde as tilde,
    hinge_rotation as hinge_rotation,
    body_rotations as body_rotations,
    relative_rotations as relative_rotations,
    dcm_rate as dcm_rate,
)
from ._src.dynamics import (
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
from ._src.linearize import (
    LinearSystem as LinearSystem,
    PartialLinearization as PartialLinearization,
    Structure as Structure,
    linearized_equations as linearized_equations,
    linearize as linearize,
    linearize_vehicle as linearize_vehicle,
    structure as structure,
)
from ._src.modes import (
    Modes as Modes,
    ModalError as ModalError,
    UnstableError as UnstableError,
    DefectiveError as DefectiveError,
    modes as modes,
    first_order as first_order,
)
from ._src.attitude import (
    AbstractAttitude as AbstractAttitude,
    DirectionCosines as DirectionCosines,
    Euler123 as Euler123,
    Quaternion as Quaternion,
)
from ._src.control import (
    AbstractController as AbstractController,
    Controller as Controller,
    HingePD as HingePD,
    HingePID as HingePID,
)
from ._src.loads import (
    PerBodyLoads as PerBodyLoads,
    BodyTorque as BodyTorque,
    GravityGradient as GravityGradient,
    CombinedLoads as CombinedLoads,
    combine_loads as combine_loads,
    thruster_pulse as thruster_pulse,
)
from ._src.simulate import (
    Problem as Problem,
    Solution as Solution,
    SimulationError as SimulationError,
    simulate as simulate,
    check_solution as check_solution,
    hinge_angle_event as hinge_angle_event,
    state_event as state_event,
    default_tolerance as default_tolerance,
)
from ._src.hybrid import (
    HybridModel as HybridModel,
    HybridSolution as HybridSolution,
    hybrid_model as hybrid_model,
    hybrid_rhs as hybrid_rhs,
    hybrid_equations as hybrid_equations,
    simulate_hybrid as simulate_hybrid,
)
from ._src.campaign import (
    monte_carlo as monte_carlo,
)
from ._src.viewer import (
    write_animation as write_animation,
    write_mode_animation as write_mode_animation,
    animation_html as animation_html,
    mode_html as mode_html,
    expand_shape as expand_shape,
)
from ._src.diagnostics import (
    Condition as Condition,
    condition as condition,
    SceneReport as SceneReport,
    check_scene as check_scene,
)
from ._src.results import (
    load_result as load_result,
    save_result as save_result,
)
from ._src.output import (
    histories as histories,
    save_npz as save_npz,
    save_csv as save_csv,
    summary as summary,
    save_plot as save_plot,
    atomic_write as atomic_write,
)
from ._src.plots import (
    plot_histories as plot_histories,
    plot_drift as plot_drift,
    plot_mode_shapes as plot_mode_shapes,
    plot_work_precision as plot_work_precision,
)
from ._src.barycentric import (
    Barycentric as Barycentric,
    barycentric as barycentric,
    coupling_inertia as coupling_inertia,
    seed_equations as seed_equations,
)
from ._src.articulated import resolve_method as resolve_method
from ._src.campaign import FAILURES as FAILURES
from ._src._integrate import Failure as Failure, DEFAULT_RTOL as DEFAULT_RTOL, DEFAULT_ATOL as DEFAULT_ATOL
from ._src.attitude import get_attitude as get_attitude
from ._src.kinematics import full_precision as full_precision
from ._src.control import hinge_torque_vector as hinge_torque_vector
from ._src.substructure import Substructure as Substructure
from ._src.substructure import substructures as substructures
from ._src._checks import SceneError as SceneError, SceneTypeError as SceneTypeError, SceneWarning as SceneWarning

# The public surface: everything a user imports comes from here (the modules under
# jaxtree._src are the implementation and may change). Grouped by the seed's ideas.
__all__ = [
    # the vehicle: scenes, the builder and the model (Sec. II D; Defs. 4-5 and 26-28)
    "Body", "Joint", "Free", "SpringDamper", "PrescribedSine", "Prescribed", "build_model", "validate_model",
    "load_scene", "scene_from_dict", "scene_to_dict", "save_scene", "scene_path", "list_scenes",
    "Model", "State", "Topology", "Prescription", "SinePrescription", "SceneError", "SceneTypeError",
    "SceneWarning",
    # kinematics (Eqs. 3-5, 21-22) and attitude variables (Eqs. 3, 23-24, quaternions)
    "tilde", "hinge_rotation", "body_rotations", "relative_rotations", "dcm_rate",
    "AbstractAttitude", "DirectionCosines", "Euler123", "Quaternion", "get_attitude",
    # Eq. (1) and Eq. (2): the unrestricted equations and their parts (Defs. 19-41)
    "forward_dynamics", "solve_accelerations", "rotational_equations", "mass_matrix", "configuration",
    "Accelerations", "hinge_torques", "kinetic_energy", "angular_momentum", "mass_center_acceleration",
    "DynamicsError", "resolve_method", "Barycentric", "barycentric", "coupling_inertia", "seed_equations",
    "full_precision",
    # hinge laws, controllers and external loads (Defs. 19-21, Sec. II D inputs 7-8)
    "AbstractController", "Controller", "HingePD", "HingePID", "hinge_torque_vector",
    "BodyLoads", "FunctionLoads", "PerBodyLoads", "BodyTorque", "GravityGradient", "CombinedLoads",
    "combine_loads", "thruster_pulse",
    # simulation of Eq. (1) (Eqs. 25-27 with diffrax), events, failures
    "simulate", "Solution", "Problem", "SimulationError", "Failure", "check_solution", "hinge_angle_event",
    "state_event", "default_tolerance", "DEFAULT_RTOL", "DEFAULT_ATOL",
    # partial linearization (Eqs. 28-69) and modes (Eqs. 70-104)
    "linearize", "linearize_vehicle", "linearized_equations", "structure", "LinearSystem",
    "PartialLinearization", "Structure", "modes", "first_order", "Modes", "ModalError", "UnstableError",
    "DefectiveError",
    # hybrid coordinates (Eqs. 105-123)
    "hybrid_model", "simulate_hybrid", "HybridModel", "HybridSolution", "hybrid_rhs", "hybrid_equations",
    "Substructure", "substructures",
    # campaigns, diagnostics, result files, plots and the 3D viewer
    "monte_carlo", "FAILURES", "condition", "Condition", "check_scene", "SceneReport", "load_result",
    "save_result", "histories", "save_npz", "save_csv", "save_plot", "summary", "atomic_write", "plot_histories", "plot_drift", "plot_mode_shapes", "plot_work_precision",
    "write_animation", "write_mode_animation", "animation_html", "mode_html", "expand_shape",
]
