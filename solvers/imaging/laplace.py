"""The Laplace band of a stiffness map: the posterior's covariance at the estimate, from the
Gauss-Newton Hessian of eq. (I8) (docs/imaging.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.imaging.estimate import FieldEstimate


@dataclass
class Laplace:
    """The Laplace approximation around an estimate: Gauss-Newton Hessian of eq. (I8)."""

    std: np.ndarray
    """Pointwise standard deviation of s = log(E / E_ref) at the nodes."""
    effective_dof: float
    """tr((J^T J + beta R'')^-1 J^T J): parameters the data determine."""
    rank: int
    """Eigenpairs kept (N when dense)."""
    covariance: np.ndarray
    """(J^T J + beta R'')^-1 (low rank: P^-1 - V diag(lambda / (1 + lambda)) V^T), (N, N)."""

    def pointwise_std(self, phi) -> np.ndarray:
        """Standard deviation of s at points with field basis rows ``phi`` (n, N)."""
        phi = sp.csr_matrix(phi)
        variance = np.asarray(phi.multiply(phi @ self.covariance).sum(axis=1)).ravel()
        return np.sqrt(np.maximum(variance, 0.0))


def laplace(
    fp, regularizer, estimate: FieldEstimate, rank: int | None = None, nuisance=None
) -> Laplace:
    """Posterior standard deviations and effective dof.

    Dense (J formed) when ``rank`` is None; otherwise low rank: the ``rank`` largest
    eigenpairs of J^T J v = lambda P v, P = beta R'' + delta I (delta: 1e-6 of P's
    largest diagonal, for the constant mode R does not see), found with matrix-free
    products (one forward and one adjoint solve per case each), so that
    H^-1 ~ P^-1 - V diag(lambda / (1 + lambda)) V^T.

    ``nuisance`` (n_residuals, p): the columns d r / d theta of parameters held at
    their estimates (the model's nu), with a flat prior. The field's covariance is
    then the marginal one, the inverse of the Schur complement of the joint
    Gauss-Newton Hessian [[H, B], [B^T, D]] (B = J^T N, D = N^T N):

        C = H^-1 + H^-1 B (D - B^T H^-1 B)^-1 B^T H^-1,                          (I9)

    so the band also holds what the field's mean trades against them.
    """
    c = estimate.coefficients
    prior = (estimate.weight * regularizer.hessian(c)).toarray()
    if rank is None:
        jac = fp.sensitivities(c) if estimate.jacobian is None else estimate.jacobian
        data = jac.T @ jac
        covariance = np.linalg.inv(data + prior)
        edof, kept = float(np.trace(covariance @ data)), fp.size
    else:
        delta = 1e-6 * max(np.max(np.diag(prior)), 1e-12)
        precision = prior + delta * np.eye(fp.size)
        operator = spla.LinearOperator(
            (fp.size, fp.size), matvec=lambda v: fp.vjp(c, fp.jvp(c, np.ravel(v)))
        )
        k = min(rank, fp.size - 1)
        values, vectors = spla.eigsh(operator, k=k, M=sp.csr_matrix(precision))
        values = np.maximum(values, 0.0)
        correction = (vectors * (values / (1.0 + values))) @ vectors.T
        covariance = np.linalg.inv(precision) - correction
        edof, kept = float(np.sum(values / (1 + values))), len(values)
    if nuisance is not None:
        columns = np.asarray(nuisance, dtype=float).reshape(fp.n_residuals, -1)
        coupling = np.column_stack([fp.vjp(c, n) for n in columns.T])  # B = J^T N
        cross = covariance @ coupling  # H^-1 B
        schur = columns.T @ columns - coupling.T @ cross
        covariance = covariance + cross @ np.linalg.solve(schur, cross.T)
    std = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    return Laplace(std, edof, kept, covariance)
