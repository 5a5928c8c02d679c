"""Studies in time on the phantom.

- ``transient``: the transient from rest against the static equilibrium (``dvs transient``);
- ``inverse``: mu and gamma from marker trajectories (``dvs dynamic``).
"""
