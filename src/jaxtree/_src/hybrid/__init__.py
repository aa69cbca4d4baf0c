"""Hybrid-coordinate equations in truncated large-deformation modal coordinates: Sec. III E of
Likins (1972), Eqs. (105)-(123).

The vehicle is split as in Sec. III A-B: the set A of *small* hinges (the even groups
``gamma^2, gamma^4, ...`` of Eq. 30c; ``nu`` of them) and the *large* variables (``omega0`` and
the hinges not in A, the odd groups). Eq. (30), the partially linearized Eq. (1), keeps the
large variables unrestricted and the small ones to first order. The small hinges fall into
*substructures* (connected groups, e.g. one wing: :func:`jaxtree.substructures`); their
constant-coefficient equations ``I y'' + J y' + K y = 0`` (Eq. 42 = Eq. 105 per group) give the
modes (:func:`jaxtree.modes`, Eqs. 70-104) that define the *large-deformation modal coordinates*;
keeping only some modes (truncation) gives the hybrid-coordinate equations: Eq. (121) for real
modes, Eq. (118) for first-order (gyroscopic or damped) ones.

The modules, along the stages of the computation (``README.md`` beside them tells the design):

- :mod:`.substructure`: the substructures and their Taylor coefficients in the base's frame;
- :mod:`.model`: :class:`HybridModel` (its arrays and state layout, Eqs. 111-112);
- :mod:`.basis`: which modes are retained, their modal matrices (Eqs. 106-123), the truncation
  terms;
- :mod:`.arguments`: the arguments of :func:`hybrid_model`, checked and resolved;
- :mod:`.systems`: the systems whose modes are taken, their modes, the retained ones;
- :mod:`.assembly`: :func:`hybrid_model`, from the vehicle to a :class:`HybridModel`;
- :mod:`.precomputed`: Eq. (30) from the precomputed substructure terms;
- :mod:`.rhs`: the projected system (Eqs. 115-118, 121), :func:`hybrid_equations`,
  :func:`hybrid_rhs`, :func:`hybrid_jacobian`;
- :mod:`.solution`: :func:`simulate_hybrid`, :class:`HybridSolution`, the truncation estimate.
"""

from .assembly import hybrid_model as hybrid_model
from .model import HybridModel as HybridModel
from .rhs import hybrid_equations as hybrid_equations
from .rhs import hybrid_jacobian as hybrid_jacobian
from .rhs import hybrid_rhs as hybrid_rhs
from .solution import HybridSolution as HybridSolution
from .solution import simulate_hybrid as simulate_hybrid
from .substructure import Substructure as Substructure
from .substructure import substructures as substructures
