"""The equations of motion of the discrete-coordinate model (Eqs. 1-27 of Likins 1972).

``kinematics`` (rotations and path sums along the tree), ``spatial`` (six-dimensional rigid-body
algebra), ``attitude`` (direction cosines, Euler angles, quaternions), ``control`` and ``loads``
(hinge laws, controllers, external forces and torques), ``barycentric`` (the printed Eq. (1) term
by term), ``dynamics`` (Eq. (1) dense, its derivatives, Eq. (2), energy and momentum),
``articulated`` (Eq. (1) by a blocked articulated-body recursion), ``batched`` (the same recursion
laid out for a batch) and ``diagnostics`` (the condition of Eq. (1)). The small linear algebra both
solvers share is in :mod:`jaxtree._src.numerics`.
The design of the two solvers and of their derivatives is in ``README.md`` beside this file.
"""
