"""The field ``dvs image`` maps on when ``--field`` is not given (``--field auto``).

As step 0 chooses the volume from the markers, the field's nodes follow the markers
(docs/imaging.md, "The field's size"):

1. **Spacing.** The field is piecewise linear (degree 1): the narrowest bump it can hold
   is one node's hat, 2 h wide for a node spacing h. The markers sample the tissue every
   s (``marker_spacing``), so a field whose narrowest bump is wider than s is coarser
   than the data, and its node grid, not the data, places the features of the map (the
   peak of a degree-1 map lies on a node). The target is therefore 2 h = s,
   h = ``SPACING_OF_MARKERS`` s: half a marker spacing, the ratio step 0 starts its
   volume's knot spans from (``experiments.basemodel.family.SPAN_OF_SPACING``). The
   weight, not the node count, decides how smooth the map is (eq. I8; beta in mm^2
   does not depend on the nodes), so a finer field costs time, not resolution.
2. **Extent.** The field spans the volume imaged on, the markers and the band of tissue
   beyond them (``tissue_lengths`` of the model), with the same spacing along u and v
   and, for ``--over layers`` or ``volume``, through the thickness.
3. **Cost.** At most ``AUTO_MAX_SIZE`` coefficients: when the target needs more, the
   spacing grows to the least that fits (``capped`` in the record).
"""

from __future__ import annotations

import math

AUTO_MAX_SIZE = 400
"""Largest field ``--field auto`` chooses (20 x 20): the dense Laplace approximation's
limit (``experiments.imaging.mapping.DENSE_LAPLACE_MAX_N``), above which the map's
uncertainty would be a low-rank one. The cost of a solve hardly grows with N up to it
(J is one solve with the markers' rows as right-hand sides; docs/imaging.md, "The
field's size")."""

SPACING_OF_MARKERS = 0.5
"""Target node spacing in marker spacings: one node's hat (2 h) as wide as a marker spacing."""


def nodes_along(length_mm: float, spacing_mm: float, least: int) -> int:
    """Nodes of a degree-1 field over ``length_mm`` at most ``spacing_mm`` apart."""
    return max(least, math.ceil(length_mm / spacing_mm - 1e-9) + 1)


def layout_shape(lengths_mm, spacing_mm: float, over: str) -> tuple[int, ...]:
    """The field's shape for ``over`` at node spacing ``spacing_mm`` over ``lengths_mm``
    (along u, v, w): degree 1 along u and v (and w for ``volume``); ``layers`` holds one
    constant per layer, each at most ``spacing_mm`` thick, and at least two layers (one
    is the surface field)."""
    in_plane = tuple(nodes_along(length, spacing_mm, 2) for length in lengths_mm[:2])
    if over == "surface":
        return in_plane
    if over == "layers":
        return (*in_plane, max(2, math.ceil(lengths_mm[2] / spacing_mm - 1e-9)))
    return (*in_plane, nodes_along(lengths_mm[2], spacing_mm, 2))


def choose_field(
    marker_spacing_mm: float, lengths_mm, over: str = "surface", max_size: int = AUTO_MAX_SIZE
) -> dict:
    """The field for markers ``marker_spacing_mm`` apart on a volume of ``lengths_mm``
    (u, v, w) [mm]: the module's rule, as image.json's ``field_choice``."""
    if not (marker_spacing_mm > 0 and math.isfinite(marker_spacing_mm)):
        raise ValueError(f"the marker spacing must be positive, got {marker_spacing_mm!r}")
    lengths = [float(v) for v in lengths_mm]
    target = SPACING_OF_MARKERS * marker_spacing_mm
    # the spacings at which a count changes, from the target up: the first that fits
    steps = {
        length / k
        for length in lengths
        for k in range(1, math.ceil(length / target) + 1)
        if length / k > target
    }
    spacing = target
    for candidate in [target, *sorted(steps)]:
        spacing = candidate
        if math.prod(layout_shape(lengths, candidate, over)) <= max_size:
            break
    shape = layout_shape(lengths, spacing, over)
    capped = spacing > target
    reason = (
        f"target spacing {target:.2f} mm, {SPACING_OF_MARKERS:g} of the markers' "
        f"{marker_spacing_mm:.2f} mm: one node's hat as wide as a marker spacing"
    )
    if capped:
        reason += f"; widened to fit {max_size} coefficients"
    return {
        "rule": "auto",
        "shape": list(shape),
        "marker_spacing_mm": float(marker_spacing_mm),
        "target_spacing_mm": float(target),
        "spacing_mm": node_spacings(lengths, shape, over),
        "lengths_mm": lengths,
        "capped": bool(capped),
        "reason": reason,
    }


def node_spacings(lengths_mm, shape, over: str) -> list[float]:
    """Physical distance [mm] between neighbouring nodes along u and v (and w)."""
    spacings = [length / (n - 1) for length, n in zip(lengths_mm[:2], shape[:2])]
    if over == "layers":
        spacings.append(lengths_mm[2] / shape[2])
    elif over == "volume":
        spacings.append(lengths_mm[2] / (shape[2] - 1))
    return [float(v) for v in spacings]


def field_choice(dataset, model, over: str, shape) -> dict:
    """image.json's ``field_choice`` for ``dataset`` imaged on ``model``: the rule's
    (``shape`` "auto") or the given ``shape``, with the spacing it has on this volume."""
    from experiments.problem.surroundings import marker_spacing
    from symbolic.field import tissue_lengths

    spacing = marker_spacing(dataset.outer_rest)
    lengths = tissue_lengths(model)
    if shape == "auto":
        return choose_field(spacing, lengths, over)
    shape = [int(n) for n in shape]
    return {
        "rule": "given",
        "shape": shape,
        "marker_spacing_mm": float(spacing),
        "target_spacing_mm": None,
        "spacing_mm": node_spacings(lengths, shape, over),
        "lengths_mm": [float(v) for v in lengths],
        "capped": False,
        "reason": "--field",
    }


def describe(choice: dict) -> str:
    """One line for the command's report."""
    shape = "x".join(map(str, choice["shape"]))
    spacing = " x ".join(f"{v:.1f}" for v in choice["spacing_mm"])
    lengths = " x ".join(f"{v:.0f}" for v in choice["lengths_mm"][:2])
    return (
        f"field {choice['rule']}: {shape}, nodes {spacing} mm apart over the {lengths} mm "
        f"volume; {choice['reason']}"
    )
