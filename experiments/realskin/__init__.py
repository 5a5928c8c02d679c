"""Real in vivo skin in a two-pad extensometer (docs/realskin.md, docs/realskin-data.md).

Data: ``data`` (the measurements), ``dicnoise`` (their noise) and ``geometry`` (gmsh's
region, pads, keloid). Model: ``slab`` (volume, pads, region indicator;
``symbolic.skin_slab`` the model), ``cases`` (frames and observations), ``planarfit``
(the nested fit), ``stages`` (one stage's fit and score tests), ``scan`` (a region the
data locate). The study: ``setup``, ``skinloop`` and ``skinstudy`` (``dvs realskin
fit``), with ``figures``, ``skinplots`` and ``skintables``; the continua
``skincontinuum`` and ``continuum_cells``; strain stiffening ``planarstiffening``.
Checks: ``strain`` (model-free strain), ``twin`` (a synthetic twin) and ``checks`` (of
the keloid's region), ``cellmap``. The authors' own model: ``authors`` (their set-up),
``mesh2d`` (a triangle mesh of the .geo), ``planar`` (plane-strain equilibrium and
sensitivities) and ``reproduce`` (``dvs realskin authors``).
"""
