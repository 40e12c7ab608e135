"""Mitsuba rendering of the head model: the only package that imports Mitsuba or Dr.Jit.

Entry points: :class:`~hack_render.render.scene.HeadScene` (build once, update through
``mi.traverse``), :func:`~hack_render.render.engine.ensure_variant`, the ``render``
command in :mod:`hack_render.render.cli` and ``turntable`` in
:mod:`hack_render.render.turntable_cli`. Importing this package does not import Mitsuba;
the submodules do so lazily.
"""
