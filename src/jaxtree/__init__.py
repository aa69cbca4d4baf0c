"""jaxtree: differentiable dynamics of hinge-connected rigid-body trees in JAX.

An implementation of P. W. Likins, *Large-Deformation Modal Coordinates for
Nonrigid Vehicle Dynamics*, JPL TR 32-1565 (1972).

Importing jaxtree changes four things in the process (:mod:`jaxtree._src.process`; README,
"What `import jaxtree` changes"):

- JAX's float64 mode (``jax_enable_x64``) is turned on: float64 is the default everywhere;
  float32 models (``model.astype(jnp.float32)``) work for GPU batches. ``JAXTREE_ENABLE_X64=0``
  in the environment leaves JAX's setting as it is (with x64 off, models are float32).
- ``OPENBLAS_NUM_THREADS`` is set to 1 where JAX computes on the CPU, unless the environment
  sets it (a setting of yours wins); with an accelerator as JAX's default it is left alone.
- JAX's persistent compilation cache is turned on (:func:`jaxtree._src.cache.enable`), in
  ``$XDG_CACHE_HOME/jaxtree/xla`` (``~/.cache/jaxtree/xla``): a second process skips XLA's
  compilation of the programs a first one compiled. ``JAXTREE_CACHE_DIR`` moves it,
  ``JAXTREE_CACHE_DIR=0`` turns it off; a cache directory set for JAX itself is left alone.
  jaxtree's own top-level programs are kept traced there too (:mod:`jaxtree._src.programs`;
  ``JAXTREE_PROGRAM_CACHE=0`` turns that part off), so a second process skips their tracing.
- Where the CPU is JAX's default backend and JAX has not started yet, it gets one device per core
  (``jax_num_cpu_devices``), so that campaigns run on every core; a program of one member still
  runs on the first. ``JAXTREE_HOST_DEVICES=1`` keeps one device; a count set in ``XLA_FLAGS``
  or JAX's configuration wins.
"""

from ._src import process as _process

_process.limit_openblas_threads()  # before JAX and scipy load OpenBLAS
_process.enable_x64()
_process.use_every_core()  # before anything starts JAX's backend

from ._src import cache as _cache

_cache.enable()

from ._src import VERSION as _VERSION
from ._src.appendage import Appendage as Appendage
from ._src.appendage import FEModel as FEModel
from ._src.appendage import appendage as appendage
from ._src.appendage import beam as beam
from ._src.appendage import held_interface_modes as held_interface_modes
from ._src.appendage import load_appendage as load_appendage
from ._src.appendage import load_fe as load_fe
from ._src.appendage import plate as plate
from ._src.appendage import plate_edge as plate_edge
from ._src.appendage import read_matrix_market as read_matrix_market
from ._src.appendage import read_op4 as read_op4
from ._src.appendage import save_appendage as save_appendage
from ._src.appendage import save_fe as save_fe
from ._src.campaigns.campaign import (
    monte_carlo as monte_carlo,
)
from ._src.campaigns.members import FAILURES as FAILURES
from ._src.equations.articulated import resolve_method as resolve_method
from ._src.equations.attitude import (
    AbstractAttitude as AbstractAttitude,
)
from ._src.equations.attitude import (
    DirectionCosines as DirectionCosines,
)
from ._src.equations.attitude import (
    Euler123 as Euler123,
)
from ._src.equations.attitude import (
    Quaternion as Quaternion,
)
from ._src.equations.attitude import get_attitude as get_attitude
from ._src.equations.barycentric import (
    Barycentric as Barycentric,
)
from ._src.equations.barycentric import (
    barycentric as barycentric,
)
from ._src.equations.barycentric import (
    coupling_inertia as coupling_inertia,
)
from ._src.equations.barycentric import (
    seed_equations as seed_equations,
)
from ._src.equations.control import (
    AbstractController as AbstractController,
)
from ._src.equations.control import (
    Controller as Controller,
)
from ._src.equations.control import (
    HingePD as HingePD,
)
from ._src.equations.control import (
    HingePID as HingePID,
)
from ._src.equations.control import hinge_torque_vector as hinge_torque_vector
from ._src.equations.diagnostics import (
    Condition as Condition,
)
from ._src.equations.diagnostics import (
    condition as condition,
)
from ._src.equations.dynamics import (
    Accelerations as Accelerations,
)
from ._src.equations.dynamics import (
    DynamicsError as DynamicsError,
)
from ._src.equations.dynamics import (
    angular_momentum as angular_momentum,
)
from ._src.equations.dynamics import (
    configuration as configuration,
)
from ._src.equations.dynamics import (
    forward_dynamics as forward_dynamics,
)
from ._src.equations.dynamics import (
    hinge_torques as hinge_torques,
)
from ._src.equations.dynamics import (
    kinetic_energy as kinetic_energy,
)
from ._src.equations.dynamics import (
    mass_center_acceleration as mass_center_acceleration,
)
from ._src.equations.dynamics import (
    mass_matrix as mass_matrix,
)
from ._src.equations.dynamics import (
    rotational_equations as rotational_equations,
)
from ._src.equations.dynamics import (
    solve_accelerations as solve_accelerations,
)
from ._src.equations.kinematics import (
    body_rotations as body_rotations,
)
from ._src.equations.kinematics import (
    dcm_rate as dcm_rate,
)
from ._src.equations.kinematics import full_precision as full_precision
from ._src.equations.kinematics import (
    hinge_rotation as hinge_rotation,
)
from ._src.equations.kinematics import (
    relative_rotations as relative_rotations,
)
from ._src.equations.kinematics import (
    tilde as tilde,
)
from ._src.equations.loads import (
    AttitudePD as AttitudePD,
)
from ._src.equations.loads import (
    BodyTorque as BodyTorque,
)
from ._src.equations.loads import (
    CircularOrbit as CircularOrbit,
)
from ._src.equations.loads import (
    CombinedLoads as CombinedLoads,
)
from ._src.equations.loads import (
    GravityGradient as GravityGradient,
)
from ._src.equations.loads import (
    PerBodyLoads as PerBodyLoads,
)
from ._src.equations.loads import (
    ScheduledLoads as ScheduledLoads,
)
from ._src.equations.loads import (
    combine_loads as combine_loads,
)
from ._src.equations.loads import (
    thruster_pulse as thruster_pulse,
)
from ._src.errors import SceneError as SceneError
from ._src.errors import SceneTypeError as SceneTypeError
from ._src.errors import SceneWarning as SceneWarning
from ._src.hybrid import (
    HybridModel as HybridModel,
)
from ._src.hybrid import (
    HybridSolution as HybridSolution,
)
from ._src.hybrid import Substructure as Substructure
from ._src.hybrid import (
    hybrid_equations as hybrid_equations,
)
from ._src.hybrid import (
    hybrid_jacobian as hybrid_jacobian,
)
from ._src.hybrid import (
    hybrid_model as hybrid_model,
)
from ._src.hybrid import (
    hybrid_rhs as hybrid_rhs,
)
from ._src.hybrid import (
    simulate_hybrid as simulate_hybrid,
)
from ._src.hybrid import substructures as substructures
from ._src.hybrid.linear import (
    linearize as linearize,
)
from ._src.hybrid.linear import (
    linearize_vehicle as linearize_vehicle,
)
from ._src.identify import ConvergenceWarning as ConvergenceWarning
from ._src.identify import Fit as Fit
from ._src.identify import IdentifiabilityWarning as IdentifiabilityWarning
from ._src.identify import body_rates as body_rates
from ._src.identify import identify as identify
from ._src.identify import load_record as load_record
from ._src.identify import plot_residuals as plot_residuals
from ._src.identify import save_record_csv as save_record_csv
from ._src.identify import with_quantities as with_quantities
from ._src.integration.autosolver import (
    SolverChoice as SolverChoice,
)
from ._src.integration.autosolver import (
    choose_solver as choose_solver,
)
from ._src.integration.core import DEFAULT_ATOL as DEFAULT_ATOL
from ._src.integration.core import DEFAULT_RTOL as DEFAULT_RTOL
from ._src.integration.core import default_tolerance as default_tolerance
from ._src.integration.events import hinge_angle_event as hinge_angle_event
from ._src.integration.events import state_event as state_event
from ._src.integration.failures import Failure as Failure
from ._src.integration.failures import SimulationError as SimulationError
from ._src.integration.problem import Problem as Problem
from ._src.integration.radau import Radau5 as Radau5
from ._src.integration.rk4 import RK4 as RK4
from ._src.integration.simulate import simulate as simulate
from ._src.integration.solution import Solution as Solution
from ._src.integration.solution import check_solution as check_solution
from ._src.io.history_plots import (
    plot_drift as plot_drift,
)
from ._src.io.history_plots import (
    plot_histories as plot_histories,
)
from ._src.io.mode_plots import (
    plot_mode_shapes as plot_mode_shapes,
)
from ._src.io.output import (
    atomic_write as atomic_write,
)
from ._src.io.output import (
    histories as histories,
)
from ._src.io.output import (
    save_csv as save_csv,
)
from ._src.io.output import (
    save_npz as save_npz,
)
from ._src.io.output import (
    save_plot as save_plot,
)
from ._src.io.output import (
    summary as summary,
)
from ._src.io.result_files import (
    load_result as load_result,
)
from ._src.io.result_files import (
    save_result as save_result,
)
from ._src.io.viewer import (
    animation_html as animation_html,
)
from ._src.io.viewer import (
    expand_shape as expand_shape,
)
from ._src.io.viewer import (
    mode_html as mode_html,
)
from ._src.io.viewer import (
    write_animation as write_animation,
)
from ._src.io.viewer import (
    write_mode_animation as write_mode_animation,
)
from ._src.io.work_precision_plot import (
    plot_work_precision as plot_work_precision,
)
from ._src.linear.linearize import (
    LinearSystem as LinearSystem,
)
from ._src.linear.linearize import (
    PartialLinearization as PartialLinearization,
)
from ._src.linear.linearize import (
    Structure as Structure,
)
from ._src.linear.linearize import (
    linearized_equations as linearized_equations,
)
from ._src.linear.linearize import (
    structure as structure,
)
from ._src.linear.modes import (
    DefectiveError as DefectiveError,
)
from ._src.linear.modes import (
    ModalError as ModalError,
)
from ._src.linear.modes import (
    Modes as Modes,
)
from ._src.linear.modes import (
    UnstableError as UnstableError,
)
from ._src.linear.modes import (
    first_order as first_order,
)
from ._src.linear.modes import (
    modes as modes,
)
from ._src.scene.appendages import scene_appendages as scene_appendages
from ._src.scene.check import (
    SceneReport as SceneReport,
)
from ._src.scene.check import (
    check_scene as check_scene,
)
from ._src.scene.files import (
    list_scenes as list_scenes,
)
from ._src.scene.files import (
    load_scene as load_scene,
)
from ._src.scene.files import (
    save_scene as save_scene,
)
from ._src.scene.files import (
    scene_from_dict as scene_from_dict,
)
from ._src.scene.files import (
    scene_path as scene_path,
)
from ._src.scene.files import (
    scene_to_dict as scene_to_dict,
)
from ._src.scene.joints import (
    Body as Body,
)
from ._src.scene.joints import (
    Free as Free,
)
from ._src.scene.joints import (
    Joint as Joint,
)
from ._src.scene.joints import (
    Prescribed as Prescribed,
)
from ._src.scene.joints import (
    PrescribedRamp as PrescribedRamp,
)
from ._src.scene.joints import (
    PrescribedSine as PrescribedSine,
)
from ._src.scene.joints import (
    PrescribedSmoothStep as PrescribedSmoothStep,
)
from ._src.scene.joints import (
    PrescribedTable as PrescribedTable,
)
from ._src.scene.joints import (
    SpringDamper as SpringDamper,
)
from ._src.scene.scene import (
    build_model as build_model,
)
from ._src.vehicle.model import (
    BodyLoads as BodyLoads,
)
from ._src.vehicle.model import (
    FunctionLoads as FunctionLoads,
)
from ._src.vehicle.model import (
    Model as Model,
)
from ._src.vehicle.model import (
    Prescription as Prescription,
)
from ._src.vehicle.model import (
    SinePrescription as SinePrescription,
)
from ._src.vehicle.model import (
    State as State,
)
from ._src.vehicle.topology import Topology as Topology
from ._src.vehicle.validate import (
    validate_model as validate_model,
)

__version__ = _VERSION

# The public surface: everything a user imports comes from here (the modules under
# jaxtree._src are the implementation and may change). Grouped by the seed's ideas.
__all__ = [
    # the vehicle: scenes, the builder and the model (Sec. II D; Defs. 4-5 and 26-28)
    "Body",
    "Joint",
    "Free",
    "SpringDamper",
    "PrescribedSine",
    "PrescribedRamp",
    "PrescribedSmoothStep",
    "PrescribedTable",
    "Prescribed",
    "build_model",
    "validate_model",
    "load_scene",
    "scene_from_dict",
    "scene_to_dict",
    "save_scene",
    "scene_path",
    "list_scenes",
    "Model",
    "State",
    "Topology",
    "Prescription",
    "SinePrescription",
    "SceneError",
    "SceneTypeError",
    "SceneWarning",
    # kinematics (Eqs. 3-5, 21-22) and attitude variables (Eqs. 3, 23-24, quaternions)
    "tilde",
    "hinge_rotation",
    "body_rotations",
    "relative_rotations",
    "dcm_rate",
    "AbstractAttitude",
    "DirectionCosines",
    "Euler123",
    "Quaternion",
    "get_attitude",
    # Eq. (1) and Eq. (2): the unrestricted equations and their parts (Defs. 19-41)
    "forward_dynamics",
    "solve_accelerations",
    "rotational_equations",
    "mass_matrix",
    "configuration",
    "Accelerations",
    "hinge_torques",
    "kinetic_energy",
    "angular_momentum",
    "mass_center_acceleration",
    "DynamicsError",
    "resolve_method",
    "Barycentric",
    "barycentric",
    "coupling_inertia",
    "seed_equations",
    "full_precision",
    # hinge laws, controllers and external loads (Defs. 19-21, Sec. II D inputs 7-8)
    "AbstractController",
    "Controller",
    "HingePD",
    "HingePID",
    "hinge_torque_vector",
    "BodyLoads",
    "FunctionLoads",
    "PerBodyLoads",
    "BodyTorque",
    "GravityGradient",
    "CombinedLoads",
    "combine_loads",
    "thruster_pulse",
    "ScheduledLoads",
    "AttitudePD",
    "CircularOrbit",
    # simulation of Eq. (1) (Eqs. 25-27 with diffrax), events, failures
    "simulate",
    "Solution",
    "Problem",
    "SimulationError",
    "Failure",
    "check_solution",
    "hinge_angle_event",
    "state_event",
    "choose_solver",
    "SolverChoice",
    "RK4",
    "Radau5",
    "default_tolerance",
    "DEFAULT_RTOL",
    "DEFAULT_ATOL",
    # partial linearization (Eqs. 28-69) and modes (Eqs. 70-104)
    "linearize",
    "linearize_vehicle",
    "linearized_equations",
    "structure",
    "LinearSystem",
    "PartialLinearization",
    "Structure",
    "modes",
    "first_order",
    "Modes",
    "ModalError",
    "UnstableError",
    "DefectiveError",
    # hybrid coordinates (Eqs. 105-123)
    "hybrid_model",
    "simulate_hybrid",
    "HybridModel",
    "HybridSolution",
    "hybrid_jacobian",
    "hybrid_rhs",
    "hybrid_equations",
    "Substructure",
    "substructures",
    # finite-element appendages: held-interface modes, modal invariants, geometric stiffness
    "FEModel",
    "beam",
    "plate",
    "plate_edge",
    "held_interface_modes",
    "Appendage",
    "appendage",
    "load_fe",
    "save_fe",
    "read_matrix_market",
    "read_op4",
    "load_appendage",
    "save_appendage",
    "scene_appendages",
    # campaigns, diagnostics, result files, plots and the 3D viewer
    "monte_carlo",
    "FAILURES",
    "condition",
    "Condition",
    "check_scene",
    "SceneReport",
    "load_result",
    "save_result",
    "histories",
    "save_npz",
    "save_csv",
    "save_plot",
    "summary",
    "atomic_write",
    "plot_histories",
    "plot_drift",
    "plot_mode_shapes",
    "plot_work_precision",
    "write_animation",
    "write_mode_animation",
    "animation_html",
    "mode_html",
    "expand_shape",
    # parameter identification through the simulation (the use of Eq. 1 its users named first)
    "identify",
    "with_quantities",
    "load_record",
    "save_record_csv",
    "plot_residuals",
    "Fit",
    "body_rates",
    "ConvergenceWarning",
    "IdentifiabilityWarning",
]


# Error against run time lives in :mod:`jaxtree.bench`, outside the engine and its ``__all__``;
# its names stay reachable here, imported on first use (``jaxtree.work_precision`` ...).
_BENCH = {
    "work_precision": "work_precision",
    "BenchReport": "BenchReport",
    "BenchCase": "BenchCase",
    "bench_case": "bench_case",
    "BENCH_CASES": "CASES",
    "stiff_chain": "stiff_chain",
}


def __getattr__(name):
    if name in _BENCH:
        from . import bench

        return getattr(bench, _BENCH[name])
    raise AttributeError(f"module 'jaxtree' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_BENCH])


# what `import jaxtree` defined, recorded: a name rebound later (a monkeypatch) keeps the kept
# programs of jaxtree._src.programs off while it lasts
from ._src import programs as _programs

_programs.record()
