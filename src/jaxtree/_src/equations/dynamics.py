"""The unrestricted discrete-coordinate equations: Eq. (1) and Eq. (2) of Likins (1972).

The names of Eq. (1)'s evaluation, gathered from the modules that hold them (the rest of jaxtree
imports them from here):

- :mod:`.assembly`: the matrix (Defs. 38-40) and right side (Def. 41, hinge torques) of Eq. (1),
  the configuration, the unbalanced force, energy and momentum, Eq. (2);
- :mod:`.solve`: the solve of Eq. (1) for one member (Cholesky or the articulated recursion,
  prescribed hinges as in Sec. II B) and its dispatch to the batch-first recursion under
  ``jax.vmap``;
- :mod:`.rules`: its derivative (``custom_jvp``, the implicit-function rule) and batching
  (``custom_vmap``) rules;
- :mod:`.forward`: the calls of users and of the engine (``forward_dynamics``,
  ``solve_accelerations``, ``solve_unchecked``) and the diagnosis of a failed solve;
- :mod:`.diagnostics`: the condition of Eq. (1).

The rules of the batch dispatch (``BATCH_FIRST_MIN``, ``BATCH_FIRST_MIN_ACCELERATOR`` of
:mod:`.solve`, ``BATCH_FIRST_DERIVATIVES_MIN`` of :mod:`.rules`) live in those modules with the
measurements behind them; :func:`.solve.batch_first` and :func:`.solve.solve_one` call either path
explicitly.
"""

from __future__ import annotations

from ..numerics import SINGULAR_PIVOT as SINGULAR_PIVOT
from . import assembly, forward, rules, solve
from .assembly import Configuration as Configuration
from .assembly import angular_momentum as angular_momentum
from .assembly import body_angular_velocities as body_angular_velocities
from .assembly import complete_state as complete_state
from .assembly import configuration as configuration
from .assembly import configuration_and_rates as configuration_and_rates
from .assembly import energy_and_momentum as energy_and_momentum
from .assembly import external_loads as external_loads
from .assembly import hinge_torques as hinge_torques
from .assembly import kinetic_energy as kinetic_energy
from .assembly import mass_center_acceleration as mass_center_acceleration
from .assembly import mass_center_velocities as mass_center_velocities
from .assembly import mass_matrix as mass_matrix
from .assembly import merge_outboard_sums as merge_outboard_sums
from .assembly import rotational_equations as rotational_equations
from .assembly import unbalanced as unbalanced
from .diagnostics import SINGULAR_CONDITION as SINGULAR_CONDITION
from .diagnostics import matrix_condition as matrix_condition
from .diagnostics import null_direction_text as null_direction_text
from .diagnostics import unknown_labels as unknown_labels
from .diagnostics import unknown_rows as unknown_rows
from .forward import DynamicsError as DynamicsError
from .forward import forward_dynamics as forward_dynamics
from .forward import solve_accelerations as solve_accelerations
from .forward import solve_unchecked as solve_unchecked
from .solve import Accelerations as Accelerations
from .solve import batch_first_min as batch_first_min

# the names these functions had here before the split (the tests use some)
_dtype = assembly.dtype_of
_solve_plain = solve.solve_plain
_solve_members = solve.solve_members
_solve_completed = rules.solve_completed
_cholesky_solve = solve.cholesky_solve
_solve_completed_jvp = rules.solve_completed_jvp
_configuration_tangent = rules.configuration_tangent
_diagnose = forward.diagnose
