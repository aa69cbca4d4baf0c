"""The scene format: a vehicle described in ``jaxtree-scene/1`` files or by builder calls, read,
checked as text and written back; a boundary beside :mod:`jaxtree._src.io`, which the engine
(equations, integration, linear, hybrid, campaigns) never imports.

``scene`` (the builder: bodies and joint laws checked into a model), ``joints`` (the bodies and
the closed family of joint laws a user writes), ``files`` (the format read and written, the
bundled scenes),
``keys`` (unknown keys refused, extension keys read past), ``laws`` (a scene's optional
``loads``, ``control`` and ``orbit`` keys, which build the hinge laws and loads of
:mod:`jaxtree._src.equations`), ``appendages`` (a scene's finite-element appendages) and
``check`` (:func:`check_scene`, what ``jaxtree check`` prints). The validation of a model's
leaves is the vehicle's (:mod:`jaxtree._src.vehicle.validate`).
"""
