"""Stiffness imaging (docs/imaging.md): ``fieldproblem`` (a field of Young's modulus
behind the markers), ``fieldsensitivity`` (its force operators, eq. I6), ``estimate``
(the regularised estimate three ways, and its Laplace band), ``regularization`` (H1,
TV), ``weight`` (Morozov, GCV, L-curve) and ``fielddesign`` (the next press, I11-I14)."""
