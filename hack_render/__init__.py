"""hack-render: the HACK head-and-neck model, rendered and fitted with Mitsuba 3.

Layers (see README.md and docs/):
  hack_render.geometry  G(beta, psi, theta, eta, tau) in torch
  appearance            A(alpha) texture model in torch
  hack_render.render    the only Mitsuba / Dr.Jit code
  hack_render.fit       inverse rendering
"""

__version__ = "0.1.0"
