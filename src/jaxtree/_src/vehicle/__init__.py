"""The vehicle (Sec. II of Likins 1972): its tree of hinge-connected bodies, as every stage reads it.

``topology`` (the static tables of Defs. 4-5 and 26-28), ``model`` (the :class:`Model` and
:class:`State` that every equation reads), ``hinges`` (the subsets of hinges the equations treat
apart, shared by the equations, the integration, the linearization and the hybrid model),
``profiles`` (prescribed angles and load histories) and ``validate`` (the checks of a model's
leaves, one model or a batch, before anything is traced). The scene format that builds a model
from text is :mod:`jaxtree._src.scene`, above the engine.
"""
