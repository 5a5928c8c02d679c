"""``python -m experiments.realskin``: the real-skin study (``dvs realskin fit``)."""

from experiments.realskin.skinfit import main

raise SystemExit(main())
