"""The equations of motion of the discrete-coordinate model (Eqs. 1-27 of Likins 1972).

``kinematics`` (rotations and path sums along the tree), ``spatial`` (six-dimensional rigid-body
algebra), ``attitude`` (direction cosines, Euler angles, quaternions), ``control`` and ``loads``
(hinge laws, controllers, external forces and torques), ``barycentric`` (the printed Eq. (1) term
by term), ``assembly`` (Eq. (1)'s matrix and right side, Eq. (2), energy and momentum), ``solve``
(Eq. (1) solved, dense or articulated, and its dispatch under ``vmap``), ``rules`` (its derivative
and batching rules), ``forward`` (the calls of Eq. (1) and the diagnosis of a failed solve),
``dynamics`` (their names, re-exported),
``articulated`` (Eq. (1) by a blocked articulated-body recursion), ``batched`` (the same recursion
laid out for a batch) and ``diagnostics`` (the condition of Eq. (1)). The small linear algebra both
solvers share is in :mod:`jaxtree._src.numerics`.
The design of the two solvers and of their derivatives is in ``README.md`` beside this file.
"""
