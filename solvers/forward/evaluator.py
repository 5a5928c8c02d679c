"""CasADi sparse Jacobians evaluated into scipy matrices: the pattern read once, the values
filled in place at every call (the Newton steps' K and the KKT matrix)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from symbolic.model import TissueModel


class SparseEvaluator:
    """Evaluates a CasADi Function with sparse outputs straight into scipy CSC matrices.

    The outputs' patterns are read once; each call writes the nonzeros into numpy
    buffers through ``Function.buffer`` (no Python lists, no DM).
    """

    def __init__(self, function: ca.Function):
        self.buffer, self.trigger = function.buffer()
        self.patterns, self.outputs = [], []
        for i in range(function.n_out()):
            pattern = function.sparsity_out(i)
            indptr, indices = (np.asarray(v) for v in pattern.get_ccs())
            self.patterns.append((indptr, indices, pattern.shape))
            self.outputs.append(np.zeros(pattern.nnz()))
            self.buffer.set_res(i, memoryview(self.outputs[-1]))
        self._inputs: list = []

    def evaluate(self, *args) -> list[sp.csc_matrix]:
        """Every output at the inputs (numpy arrays, vec'd column-major as CasADi does)."""
        self._inputs = [np.ascontiguousarray(np.asarray(a, dtype=float).T.ravel()) for a in args]
        for i, value in enumerate(self._inputs):
            self.buffer.set_arg(i, memoryview(value))
        self.trigger()
        return [
            sp.csc_matrix((values.copy(), indices, indptr), shape=shape)
            for values, (indptr, indices, shape) in zip(self.outputs, self.patterns)
        ]

    def __call__(self, *args) -> sp.csc_matrix:
        """The first output."""
        return self.evaluate(*args)[0]


def casadi_to_scipy(matrix: ca.DM) -> sp.csc_matrix:
    """A CasADi sparse DM as a scipy CSC matrix."""
    pattern = matrix.sparsity()
    indptr, indices = pattern.get_ccs()
    return sp.csc_matrix((np.asarray(matrix.nonzeros()), indices, indptr), shape=matrix.shape)


def kkt_jacobian(model: TissueModel, names: tuple[str, ...]):
    """dg/ds(s, x, F_B, d) = [[K_T, C^T], [C, 0]] from the model's numeric tangent
    (``TissueModel.tangent``), as scipy CSC; None when the model has none (use AD)."""
    tangent = model.tangent(tuple(names))
    if tangent is None:
        return None
    coupling = sp.kron(sp.identity(3), model._constraint_free).tocsc()

    def jacobian(state, x, force, prescribed) -> sp.csc_matrix:
        matrix = tangent(state, x)
        if coupling.shape[0] == 0:
            return matrix
        return sp.bmat([[matrix, coupling.T], [coupling, None]], format="csc")

    return jacobian
