"""Parameter identification through the simulation: named parameters (:mod:`.quantities`,
:mod:`.parameters`), sensor models (:mod:`.sensors`) and the fit (:mod:`.fit`)."""

from .fit import REASONS as REASONS
from .fit import ConvergenceWarning as ConvergenceWarning
from .fit import Fit as Fit
from .fit import IdentifiabilityWarning as IdentifiabilityWarning
from .fit import identify as identify
from .parameters import with_quantities as with_quantities
from .record import load_record as load_record
from .record import plot_residuals as plot_residuals
from .record import save_record_csv as save_record_csv
from .sensors import body_rates as body_rates
