"""Real in vivo skin in a two-pad extensometer (docs/realskin.md, docs/realskin-data.md).

Data: ``data`` (the measurements, noise) and ``geometry`` (gmsh's region, pads, keloid).
Model: ``slab`` (volume, pads, region indicator), ``model`` (``SkinSlabModel``), ``cases``
(frames and observations), ``solve`` (the nested fit), ``stages`` (one stage's fit and
score tests), ``scan`` (a region the data locate). The study: ``setup``, ``loop`` and
``study`` (``dvs realskin fit``), with ``figures``, ``plots`` and ``report``. Checks: ``strain``
(model-free strain), ``twin`` (a synthetic twin) and ``checks`` (of the keloid's region).
The authors' own model: ``authors`` (their set-up), ``mesh2d`` (a triangle mesh of the
.geo), ``planar`` (plane-strain equilibrium and sensitivities) and ``reproduce``
(``dvs realskin authors``).
"""
