"""The scene: a vehicle described in the ``jaxtree-scene/1`` format or by builder calls.

``scene`` (the format read and written, the builder, the closed family of joint laws,
``validate_model`` and ``check_model``), ``laws`` (a scene's optional ``loads``, ``control`` and
``orbit`` keys, which build the hinge laws and loads of :mod:`jaxtree._src.equations`) and
``check`` (:func:`check_scene`, what ``jaxtree check`` prints). This stage comes after the
equations because a scene builds their laws and loads.
"""
