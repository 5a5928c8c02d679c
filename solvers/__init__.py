"""How the model is solved: forward, inverse, imaging, diagnosis and design.

- ``linalg``: sparse factorisations (``cholmod``: CHOLMOD when the system has it,
  SuperLU otherwise) and BLAS threads (``blas``);
- ``forward``: the static equilibrium (``equilibrium``: Newton on eq. 22 of
  docs/model.md; ``componentwise``: the linear model on one scalar factorisation);
  ``transient``: time stepping against it (docs/transient.md);
- ``inverse`` (docs/inverse.md): the problem stated once, the nested and simultaneous
  methods, their result, the noise model, the verdict, identifiability; ``dynamic``:
  the inverse from trajectories (docs/dynamic.md);
- ``imaging`` (docs/imaging.md): a stiffness field, its estimate, weight and next press;
- ``diagnosis``: the discrepancy loop (docs/diagnosis.md); ``design``: experiment
  design (docs/design.md).
"""
