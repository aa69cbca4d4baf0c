"""Integration over time: ``core`` (what every driver shares: tolerances, the step-size
controller, save times, failure kinds and the failure report), ``simulate`` (Eq. (1) in first-order
form, Eqs. 25-27, and :class:`Solution`), ``autosolver`` (the choice of solver from the time
scales of Eq. (42)) and ``radau`` (Radau IIA of order 5, keeping its Jacobian and factorization
over steps). The design is in ``README.md`` beside this file.
"""
