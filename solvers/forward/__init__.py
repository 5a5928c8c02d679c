"""The forward solution: ``equilibrium`` (K(B; x)(B - B0) = F_B by Newton, docs/model.md
eq. 22) and ``componentwise`` (the linear model on one scalar factorisation)."""
