"""Studies of the static inverse methods on the phantom.

- ``paper``: the paper's Table 1, two data sets separately and jointly (``dvs study paper``);
- ``compare``: simultaneous vs nested vs paper-faithful, multi-start (``dvs study compare``);
- ``bench`` (its tables ``benchtables``): build and solve times, memory and
  scaling (``dvs bench inverse``, ``make bench``);
- ``batch``: multi-start and coverage studies on dask.distributed (``dvs study batch``).
"""
