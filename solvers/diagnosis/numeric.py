"""Fast numeric evaluation of CasADi Functions into numpy/scipy arrays.

Calling a ``casadi.Function`` from Python and converting its sparse DM outputs
costs milliseconds per call (SWIG conversions), more than the evaluation
itself on the default grid. ``NumericFunction`` binds preallocated numpy
buffers once (``Function.buffer``) and returns the nonzeros as numpy arrays,
with the output sparsity patterns converted to scipy index arrays only once.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp


class NumericFunction:
    """A CasADi Function with dense inputs, evaluated through bound buffers.

    Parameters
    ----------
    function : casadi.Function
        The Function; every input must be dense.

    Calling it returns one array per output: a dense numpy array (column-major
    reshaped to the output's shape) for a dense output, a ``scipy.sparse.csc_matrix``
    otherwise. The results are copies and stay valid after the next call.
    """

    def __init__(self, function: ca.Function):
        self.function = function
        self._buffer, self._evaluate = function.buffer()
        self._inputs = []
        for i in range(function.n_in()):
            if not function.sparsity_in(i).is_dense():
                raise ValueError(f"input {function.name_in(i)} of {function.name()} must be dense")
            array = np.zeros(function.nnz_in(i))
            self._buffer.set_arg(i, memoryview(array))
            self._inputs.append(array)
        self._outputs, self._patterns = [], []
        for i in range(function.n_out()):
            pattern = function.sparsity_out(i)
            array = np.zeros(pattern.nnz())
            self._buffer.set_res(i, memoryview(array))
            self._outputs.append(array)
            if pattern.is_dense():
                self._patterns.append((pattern.shape, None, None))
            else:
                indptr, indices = pattern.get_ccs()
                self._patterns.append(
                    (
                        pattern.shape,
                        np.asarray(indptr, dtype=np.int32),
                        np.asarray(indices, dtype=np.int32),
                    )
                )

    def __call__(self, *args) -> list:
        """Evaluate at dense numeric inputs (any shapes with the right sizes)."""
        for array, value in zip(self._inputs, args):
            array[:] = np.asarray(value, dtype=float).ravel(order="F")
        self._evaluate()
        results = []
        for values, (shape, indptr, indices) in zip(self._outputs, self._patterns):
            if indptr is None:
                results.append(values.reshape(shape, order="F").copy())
            else:
                results.append(sp.csc_matrix((values.copy(), indices, indptr), shape=shape))
        return results
