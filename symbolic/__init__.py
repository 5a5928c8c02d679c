"""The model as numbers and CasADi expressions: what the tissue is, not how it is solved.

- the spline: ``basis`` (B-spline bases as sparse matrices), ``volume`` (``VolumeSpline``),
  ``elements`` (element-batched assembly), ``sparse`` (scipy <-> CasADi);
- the paper's model (docs/model.md): ``energy`` (M, D and the K terms of eq. 18),
  ``stiffening`` (K(B) of eq. 1), ``loads`` (F_B, prescribed displacements),
  ``model`` (``TissueModel``: parameters and residual), ``constraints`` (which control
  points are held), ``unitterms`` (the stiffness as unit terms, I3 (x) sum_t c_t K_t);
- the continua (docs/continuum.md): ``continuum`` (linear elasticity), ``hyperelastic``
  (neo-Hookean and exponential stiffening), ``continuum_model`` (their base models,
  ``ENERGIES``), ``field`` (a stiffness field, docs/imaging.md);
- the extensometer's slab with glued pads (docs/realskin.md): ``skin_slab``;
- ``effects``: the candidate effects of the diagnosis loop (docs/diagnosis.md).
"""
