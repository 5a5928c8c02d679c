"""How the model is solved: forward, inverse, imaging, diagnosis and design.

- forward: ``equilibrium`` (Newton on eq. 22), ``componentwise`` and ``cholmod``
  (factorisations), ``blas``; ``transient`` (time stepping, docs/transient.md);
- the inverse (docs/inverse.md): ``problem`` (stated once), ``nested`` and
  ``simultaneous`` (the two methods; ``lagrangian`` the NLP's derivatives), ``result``,
  ``noise``, ``verdict``, ``identifiability``, ``continuumfit``; ``dynamic``
  (the inverse from trajectories, docs/dynamic.md);
- stiffness imaging (docs/imaging.md): ``fieldproblem``, ``fieldsensitivity``,
  ``imaging``, ``regularization``, ``weight``;
- ``diagnosis``: the discrepancy loop (docs/diagnosis.md); ``design``: experiment
  design (docs/design.md).
"""
