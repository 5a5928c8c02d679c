"""The synthetic forehead experiment: the phantom, its designs and datasets from it.

- ``forehead``: geometry, markers, probe loads and true parameters;
- ``designs``: where and how the probe presses (the paper's design, the diagnosis design);
- ``simulate``: datasets v1 from the phantom, with hidden effects (``dvs simulate``);
- ``forward``: the deformed shape under a known force (``dvs study forward``).
"""
