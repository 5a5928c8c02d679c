"""Real in vivo skin in a two-pad extensometer (docs/realskin.md, docs/realskin-data.md).

Data: ``data`` (the measurements), ``dicnoise`` (their noise), ``geometry`` (gmsh's
region, pads, keloid outline) and ``strain`` (the model-free axial strain). Set-up:
``slab`` (volume and pads), ``cases`` (frames and observations) and ``setup`` (the base
problem of one case). The study, ``study`` (``dvs realskin fit``), runs the shared loop
(``solvers.diagnosis``) on it; ``figures`` draws what it found.
"""
