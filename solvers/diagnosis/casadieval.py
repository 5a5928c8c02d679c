"""Fast numeric evaluation of CasADi Functions into numpy/scipy arrays.

Calling a ``casadi.Function`` from Python and converting its sparse DM outputs
costs milliseconds per call (SWIG conversions), more than the evaluation
itself on the default grid. ``NumericFunction`` binds preallocated numpy
buffers once (``Function.buffer``) and returns the nonzeros as numpy arrays,
with the output sparsity patterns converted to scipy index arrays only once.

A Function's work vector holds its constants too (CasADi copies a constant matrix
into the work on every evaluation), so a linear effect's stiffness (tens of MB at
27x27x4) would sit in the buffer of every case's every Function. Above
``PERSISTENT_WORK`` the buffer is therefore made at each call and freed after it:
one Function's work in memory at a time, for a copy that costs far less than the
sparse factorisation the call feeds.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

PERSISTENT_WORK = 1 << 20
"""Work vectors up to this many doubles (8 MB) stay bound between calls."""


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
        self.persistent = function.sz_w() <= PERSISTENT_WORK
        self._buffer = None
        self._inputs = []
        for i in range(function.n_in()):
            if not function.sparsity_in(i).is_dense():
                raise ValueError(f"input {function.name_in(i)} of {function.name()} must be dense")
            self._inputs.append(np.zeros(function.nnz_in(i)))
        self._outputs, self._patterns = [], []
        for i in range(function.n_out()):
            pattern = function.sparsity_out(i)
            self._outputs.append(np.zeros(pattern.nnz()))
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

    def _bound(self):
        """A FunctionBuffer bound to the input and output arrays (kept if persistent)."""
        if self._buffer is not None:
            return self._buffer
        buffer, evaluate = self.function.buffer()
        for i, array in enumerate(self._inputs):
            buffer.set_arg(i, memoryview(array))
        for i, array in enumerate(self._outputs):
            buffer.set_res(i, memoryview(array))
        if self.persistent:
            self._buffer = (buffer, evaluate)
        return buffer, evaluate

    def __call__(self, *args) -> list:
        """Evaluate at dense numeric inputs (any shapes with the right sizes)."""
        for array, value in zip(self._inputs, args):
            array[:] = np.asarray(value, dtype=float).ravel(order="F")
        buffer, evaluate = self._bound()
        evaluate()
        if not self.persistent:
            del buffer, evaluate  # free the work (see the module's note)
        results = []
        for values, (shape, indptr, indices) in zip(self._outputs, self._patterns):
            if indptr is None:
                results.append(values.reshape(shape, order="F").copy())
            else:
                results.append(sp.csc_matrix((values.copy(), indices, indptr), shape=shape))
        return results
