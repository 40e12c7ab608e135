"""Motion synthesis and transfer (paper Sec. 6): head orientation -> neck joints
(:mod:`.head_to_neck`), expressions -> larynx slide and the Eq. 13 larynx tracker
(:mod:`.larynx_motion`), the swallow from aligned tau sequences (:mod:`.swallow`), and HACK
motion on other characters: same-topology characters (:mod:`.character`), glTF neck chains
(:mod:`.retarget`) and the command's driver (:mod:`.transfer`). :mod:`.synthetic` makes
the labelled synthetic sequences the tests and ``bench/bench_motion.py`` use; :mod:`.cli`
registers the commands.

A driver layer: it uses geometry, export, render (and deformation transfer from learn);
nothing below imports it.
"""
