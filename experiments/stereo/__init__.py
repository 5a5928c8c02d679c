"""Real-image stereo pipeline, in OpenCV's conventions (see ``docs/stereo.md``).

Modules: :mod:`.cameras` (the camera model), :mod:`.dlt` (normalised DLT),
:mod:`.calibration` (planar-target and 3D-object calibration),
:mod:`.chessboard` (corners, stereo pair from images), :mod:`.dots` (dot
detection), :mod:`.lattice` (grid lattice of the dots), :mod:`.gridlabel`
(lattice -> object indices, with its safety checks), :mod:`.colnumbers`
(the MultiDIC cylinder's printed column numbers), :mod:`.triangulation`,
:mod:`.surface` (B-spline surfaces, registration), :mod:`.multidic` (the
cylinder pipeline), :mod:`.realcheck` (the real-data checks), and for synthetic
experiments :mod:`.rig` (a three-camera rig around the phantom), :mod:`.render`
(images of the marked skin and of the calibration board) and :mod:`.reconstruct`
(an experiment folder of images -> dataset v1, ``dvs reconstruct``).

A world point ``X`` maps to camera coordinates ``x_cam = R @ X + t``; pixel
``(u, v)`` has ``u`` along image columns and ``v`` down the rows, with the
centre of the top-left pixel at (0, 0).
"""

from experiments import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "experiments.stereo.reconstruct": ("ReconstructSettings", "Reconstruction", "reconstruct"),
    },
)
