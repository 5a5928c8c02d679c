"""Cross-check of the time stepping with SUNDIALS (CVODES or IDAS) through CasADi."""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.sparse as sp

from solvers.transient.profiles import as_load
from solvers.transient.stepping import transient_solver
from symbolic.model import TissueModel
from symbolic.sparse import to_casadi_sparse


def integrate_casadi(
    model: TissueModel,
    load,
    times,
    x=None,
    names=(),
    overrides=None,
    plugin="cvodes",
    rtol=1e-10,
    atol=1e-12,
) -> np.ndarray:
    """Cross-check: SUNDIALS (CVODES, or IDAS) on the first-order system (23), from rest.

    y = [u; v], u' = v, v' = M^-1 (F(t) - f(u)) - (M^-1 D) v. M_ff is small and SPD,
    so M^-1 is formed once per component block (dense); the run starts at rest at
    ``times[0]``. ``load`` must be an array or a ``Load`` with a casadi-friendly profile.

    Returns
    -------
    numpy.ndarray
        Displacements B_free - B0_free at ``times`` (starting at 0), (k, n_free, 3) [mm].
    """
    load = as_load(load)
    solver = transient_solver(model, names)
    x, values = solver.values(x, overrides)
    n = model.n_free
    inverse = np.linalg.inv(
        values["mu"] * model.free_block(model.mass_matrix({"mu": 1.0})).toarray()
    )
    rate = inverse @ (values["gamma"] * model.free_block(model.damping_matrix({"gamma": 1.0})))
    inverse, rate = (
        to_casadi_sparse(sp.kron(sp.eye(3), sp.csc_matrix(m))) for m in (inverse, rate)
    )
    u, v, t = ca.MX.sym("u", 3 * n), ca.MX.sym("v", 3 * n), ca.MX.sym("t")
    try:
        force = ca.vec(ca.DM(np.asarray(load.force, dtype=float))) * load.profile(t)
    except Exception as error:  # any failure means "not symbolic"
        raise ValueError(
            "integrate_casadi needs a Load whose profile accepts a casadi symbol "
            "(use ca.fmin, ca.if_else)"
        ) from error
    acceleration = ca.mtimes(inverse, force - solver.internal(u, x)) - ca.mtimes(rate, v)
    dae = {"x": ca.vertcat(u, v), "t": t, "ode": ca.vertcat(v, acceleration)}
    times = np.asarray(times, dtype=float)
    options = {"abstol": atol, "reltol": rtol, "max_num_steps": 1_000_000}
    integrator = ca.integrator("transient", plugin, dae, float(times[0]), times[1:], options)
    states = np.asarray(integrator(x0=np.zeros(6 * n))["xf"])
    path = np.hstack([np.zeros((6 * n, 1)), states])[: 3 * n].T
    return path.reshape(len(times), 3, n).transpose(0, 2, 1)
