"""``python -m experiments.truthcube --out DIR [--checks]``: the Truth Cube study
(``experiments.truthcube.cubestudy.main``)."""

from experiments.truthcube.cubestudy import main

raise SystemExit(main())
