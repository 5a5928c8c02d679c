"""Studies in time on the phantom.

- ``transient``: the transient from rest against the static equilibrium (``dvs transient``);
- ``trajectories``: marker trajectories under a probe step, and their inverse problem;
- ``inverse``: mu and gamma from marker trajectories (``dvs study dynamic``).
"""
