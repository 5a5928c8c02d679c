"""The discrepancy loop: residual -> candidate effect -> refit (docs/diagnosis.md).

- ``loop``: ``diagnose`` and its settings and result (``diagnosis.json``);
- ``problem``: an inverse problem extended by effects (docs/model.md eq. 22,
  docs/inverse.md eq. 24);
- ``fit``: its nested least-squares fit;
- ``stats``: the residual test, score tests and the information criterion;
- ``guard``: the left-out-load-case check against overfitting;
- ``report``: ``report.md`` and the one-line verdict;
- ``numeric``: fast evaluation of CasADi Functions into numpy and scipy arrays.
"""
