"""The dynamic inverse: mu, gamma and alpha from marker trajectories (docs/dynamic.md).

- ``problem``: the problem stated once (trajectories, time grid, scheme);
- ``scheme``: the trapezoidal scheme and its exact forward sensitivities;
- ``simultaneous``: the discretised dynamics as constraints of one IPOPT NLP;
- ``nested``: single shooting over the scheme;
- ``identifiability``: what trajectories tell, against static data.
"""
