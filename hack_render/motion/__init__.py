"""Motion synthesis and transfer (paper Sec. 6): head orientation -> neck joints
(:mod:`.head_to_neck`), expressions -> larynx slide (:mod:`.larynx_motion`), the swallow
from aligned tau sequences (:mod:`.swallow`), and HACK motion on other characters
(:mod:`.character`, :mod:`.retarget`, :mod:`.transfer`).

A driver layer: it uses geometry, export and render; nothing below imports it.
"""
