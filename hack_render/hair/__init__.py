"""The hair layer: hair, brows, lashes and beards as strands rooted on the model's skin.

:mod:`~hack_render.hair.style` (the style space, the params file's ``hair`` section, the
population sampler), :mod:`~hack_render.hair.groom` (growing strands on the mean rest
mesh), :mod:`~hack_render.hair.pose` (posing them on any posed mesh, NumPy and torch).
"""
