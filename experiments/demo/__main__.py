"""``python -m experiments.demo``: the main job (``dvs demo``)."""

from experiments.demo.run import main

raise SystemExit(main())
