"""The hair layer: hair, brows, lashes and beards as strands rooted on the model's skin.

:mod:`~hack_render.hair.style` (the style space, the params file's ``hair`` section, the
population sampler), :mod:`~hack_render.hair.regions` (the mean rest mesh strands root on,
and where on it the scalp and the beard are), :mod:`~hack_render.hair.groom` (growing
strands there), :mod:`~hack_render.hair.pose` (posing them on any posed mesh, NumPy and
torch).
"""
