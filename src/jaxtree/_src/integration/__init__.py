"""Integration over time, split as diffrax splits its driver: ``core`` (what every driver shares:
tolerances, the step-size controller, save times and one integration), ``problem`` (Eq. (1) in
first-order form, Eqs. 25-27), ``events``, ``solution`` (:class:`Solution`), ``failures`` (the
failure kinds and their one report), ``simulate`` (the public function), ``autosolver`` (the
choice of solver from the time scales of Eq. (42); its cost model in ``autosolver_cost``, its
screen of the scene in ``autosolver_screen``, the run's right side linearized and sampled in
``autosolver_linearize``), ``save_grid`` (the default save times) and one solver a module: ``radau`` (Radau IIA
of order 5, keeping its Jacobian and factorization over steps; its coefficients and dense output in
``radau_collocation``, its factorizations in ``lu``, the Jacobians it is given in ``jacobian``) and
``rk4``. The design is in ``README.md`` beside this file.
"""
