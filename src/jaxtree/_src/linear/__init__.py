"""The linear analysis (Eqs. 28-104 of Likins 1972): ``linearize`` (the partially linearized
equations and I, J, K of Eq. (42) by ``jax.jacfwd`` about a nominal motion) and ``modes`` (the real,
gyroscopic and general modes of ``I y'' + J y' + K y = 0`` with left and right eigenvectors and
modal damping).
"""
