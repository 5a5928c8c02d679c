"""The synthetic forehead experiment: the phantom, its designs and datasets from it.

- ``forehead``: geometry, markers, probe loads and true parameters;
- ``designs``: where and how the probe presses (the paper's design, the diagnosis design);
- ``simulate``: datasets v1 from the phantom, with hidden effects (``dvs simulate``);
- ``forward``: the deformed shape under a known force (``dvs study forward``).
"""

from experiments import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "experiments.phantom.forehead": (
            "PhantomSettings",
            "forehead_model",
            "marker_uv",
            "probe_loads",
        ),
        "experiments.phantom.simulate": ("SimulationSettings", "simulate", "simulate_with_effects"),
    },
)
