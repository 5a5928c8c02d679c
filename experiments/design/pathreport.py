"""What ``dvs design --sequential`` writes besides ``sequential.json``: the path as a
table (``report.md``) and as a figure (``path.png``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.output.tables import table_lines, with_rivals


def path_table(document: dict) -> str:
    """The path of one run as a Markdown table: per step the data so far, what the
    diagnosis named (with its rivals), the RMS against the noise, the verdict, the open
    questions and the press made next."""
    lines = [
        f"Scenario `{document['scenario']}` (hidden: {document['hidden_effect'] or 'nothing'}), "
        f"start: {document['start']}, budget {document['budget']}: **{document['verdict']}** "
        f"after {document['presses']} presses, named: {', '.join(document['named']) or '-'}.",
        "",
    ]
    header = "presses | named (rivals) | RMS (um) / noise | verdict | open questions | next press"
    cells = []
    for row in document["path"]:
        press = row["press"]
        if press is None:
            chosen = f"stop: {row['stop']}"
        else:
            x, y, _ = press["contact_mm"]
            chosen = (
                f"({x:.1f}, {y:.1f}) mm, tilt {press['tilt_deg']:.0f} deg, "
                f"{np.linalg.norm(press['force_N']):.2f} N: {press['answers']}"
            )
        cells.append(
            (
                row["presses"],
                with_rivals(row["selected"], row["rivals"]),
                f"{row['rms_um']:.1f} / {row['noise_rms_um']:.1f}",
                "unexplained" if row["unexplained"] else "explained",
                len(row["open"]),
                chosen,
            )
        )
    return "\n".join(lines + table_lines(header, cells)) + "\n"


def report_text(document: dict) -> str:
    """report.md: the path, then every question of the last step with its value."""
    last = document["path"][-1]
    lines = [
        "# Sequential design (`dvs design --sequential`)",
        "",
        path_table(document),
        "## The questions at the end",
        "",
        "Value: lambda of the score test (detect, eq. D2) or the rival's lack of fit T "
        "(separate, eq. D6), against the value that answers it (docs/design.md). "
        "Unreachable: no press within the budget left would answer it.",
        "",
        *question_rows(last["questions"]),
    ]
    return "\n".join(lines) + "\n"


def question_rows(questions: list, reachable: str = "reachable") -> list[str]:
    """The questions of a step as Markdown table lines: each one's value against the value
    that answers it, answered or not, and ``reachable`` (the column's title) or not."""
    yes = {True: "yes", False: "no"}
    cells = [
        (
            q["question"],
            f"{q['value']:.3g}",
            f"{q['needed']:.3g}",
            yes[bool(q["answered"])],
            yes[bool(q["reachable"])],
        )
        for q in questions
    ]
    return table_lines(f"question | value | needed | answered | {reachable}", cells)


def plot_path(path: Path, document: dict, dataset) -> None:
    """Left: the presses on the marked area (``dataset``: every press made), the starting
    ones as crosses, the chosen ones numbered in order (arrow: the tangential force).
    Right: the RMS residual against the noise after each step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from experiments.output.atomic import atomic_savefig

    rows = document["path"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 5.2), layout="constrained")
    rest = dataset.outer_rest.reshape(-1, 3)
    left.scatter(rest[:, 0], rest[:, 1], s=6, color="0.75", label="markers")
    presses = [row["press"] for row in rows if row["press"] is not None]
    for k, press in enumerate(presses, rows[0]["presses"] + 1):
        x, y, _ = press["contact_mm"]
        fx, fy, _ = press["force_N"]
        left.plot(x, y, "o", color="crimson", ms=7)
        left.annotate("", (x + 20 * fx, y + 20 * fy), (x, y), arrowprops={"arrowstyle": "->"})
        left.annotate(str(k), (x, y), (5, 5), textcoords="offset points", color="crimson")
    start = dataset.contacts[: rows[0]["presses"]]
    left.plot(start[:, 0], start[:, 1], "kx", ms=9, mew=2, label="starting presses")
    left.plot([], [], "o", color="crimson", label="chosen presses, in order")
    left.set_aspect("equal")
    left.set_xlabel("x [mm]")
    left.set_ylabel("y [mm]")
    left.legend(loc="upper left", fontsize=8, framealpha=0.8)
    left.set_title(f"{document['scenario']}: {document['verdict']}")
    counts = [row["presses"] for row in rows]
    right.plot(counts, [row["rms_before_um"] for row in rows], "s--", label="base model")
    right.plot(counts, [row["rms_um"] for row in rows], "o-", label="after the loop")
    right.plot(counts, [row["noise_rms_um"] for row in rows], "k:", label="noise")
    for row in rows:
        right.annotate(
            ", ".join(row["selected"]) or "-",
            (row["presses"], row["rms_um"]),
            (0, 8),
            textcoords="offset points",
            fontsize=7,
            rotation=30,
        )
    right.set_xlabel("presses")
    right.set_ylabel("RMS residual [um]")
    right.legend(fontsize=8)
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)
