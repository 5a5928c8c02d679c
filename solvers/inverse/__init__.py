"""The static inverse (docs/inverse.md): ``problem`` (model, observations, parameters,
stated once), ``noise`` (the residual's covariance and whitening, eq. 24), the methods
``nested`` and ``simultaneous`` (one IPOPT NLP; ``lagrangian`` its derivatives),
``result`` (what every method returns), ``verdict`` (does the fit explain the data),
``identifiability`` and ``continuumfit`` (the homogeneous continuum's forward map)."""
