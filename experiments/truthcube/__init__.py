"""The Truth Cube (Kerdok et al. 2003) through the project's models and loop.

``cubemodel`` (the cube as a volume spline, its frame and load cases), ``cubefit`` (nu
and the plate's translations), ``cubeloop`` (the shared loop), ``cubechecks`` (the
discretisation against scikit-fem), ``cubestudy`` (the study and its command) and
``cubereport`` (its tables). docs/truthcube.md.
"""
