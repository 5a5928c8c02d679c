"""The main job, ``dvs demo`` / ``make demo``: the paper, end to end, on the phantom.

- ``run``: the steps in order, the abstract and the conclusion (``dvs demo``);
- ``sections``: one function per section, each computing its numbers and its text;
- ``markdown``: a short paper in Markdown, with numbered, captioned figures.
"""
