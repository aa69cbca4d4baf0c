"""Flexible appendages from finite-element models: a structure's mass and stiffness matrices on a
node table (:mod:`.fe`, with a beam generator of its own), reduced to its held-interface modes and
modal invariants, its share of the hybrid-coordinate equations (Eq. 30) with the geometric
stiffness of a spin's preload (:mod:`.model`), and its files (:mod:`.files`).

The report carries appendages as chains of rigid panels in large-deformation modal coordinates
(Sec. III E); a finite-element appendage enters the same equations through the same slots: its
held-interface (Craig-Bampton fixed-interface) modes are held-base modes, its Gauss function in the
base's frame gives the Taylor coefficients a substructure gives.
"""

from .fe import Elements as Elements
from .fe import FEModel as FEModel
from .fe import PlateElements as PlateElements
from .fe import beam as beam
from .fe import geometric_stiffness as geometric_stiffness
from .fe import plate as plate
from .fe import plate_edge as plate_edge
from .files import load_appendage as load_appendage
from .files import load_fe as load_fe
from .files import read_matrix_market as read_matrix_market
from .files import read_op4 as read_op4
from .files import save_appendage as save_appendage
from .files import save_fe as save_fe
from .model import Appendage as Appendage
from .model import appendage as appendage
from .model import held_interface_modes as held_interface_modes
