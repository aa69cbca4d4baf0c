"""The vehicle (Sec. II of Likins 1972): its tree of hinge-connected bodies and what builds it.

``topology`` (the static tables of Defs. 4-5 and 26-28), ``model`` (the :class:`Model` and
:class:`State` that every equation reads), ``_hinges`` (the subsets of hinges the equations treat
apart), ``scene`` (the ``jaxtree-scene/1`` format, the builder and its validation), and what a
scene may carry beyond its bodies: ``profiles`` (prescribed angles and load histories) and
``scene_laws`` (loads, hinge control and the orbit).
"""
