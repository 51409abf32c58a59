"""``report.md`` and ``compare.md`` sections of synthetic-to-real scoring: a fine model scored
through another palette, classes no ClaraVid class maps to (structural zeros), and the
fraction of the source-to-oracle gap an adapted model closes."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from claravid.eval.report.cells import gap_cell, md_table, number, with_ci


def fold_lines(source: dict[str, Any]) -> list[str]:
    """The header line of a fine model scored through another palette (none otherwise)."""
    fold = source.get("fold")
    if not fold:
        return []
    dropped = [f for f, t in fold["table"].items() if t == "ignore"]
    line = (
        f"- scored through palette {fold['palette']}, which the model was not trained on: it "
        f"predicts ClaraVid's {len(fold['table'])} classes ({fold['model_palette']}); the "
        "softmax probabilities of the fine classes are summed per palette class and the "
        "argmax taken; calibration uses the summed probabilities"
    )
    if dropped:
        line += f"; fine classes the palette ignores drop out: {', '.join(dropped)}"
    return [line]


def predictable_section(report: dict[str, Any]) -> list[str]:
    """Structural zeros: the classes no ClaraVid class reaches, the mIoU cap they imply, and
    mIoU over all classes beside mIoU over the predictable ones, per row."""
    overall = report["overall"]
    if "miou_cap" not in overall:
        return []
    predictable = report["source"].get("predictable") or []
    never = [c for c in report["classes"] if c not in predictable]
    lines = ["## Classes a ClaraVid model cannot predict", ""]
    lines.append(
        f"No ClaraVid class maps to {', '.join(never)} in this palette"
        + (" (through the fold of the fine classes)" if report["source"].get("fold") else "")
        + ": a model trained on ClaraVid cannot predict them, so wherever the ground truth holds "
        "one its IoU is 0 (a structural zero) and the mIoU is capped at (present classes − "
        "unpredictable present classes) / present classes. *mIoU, predictable* is the mean "
        "over the other classes only."
    )
    lines.append("")
    rows = []
    for row in [*report["bins"], {**overall, "name": "**overall**"}]:
        rows.append(
            [
                row["name"],
                with_ci(row["miou"], row.get("miou_ci")),
                with_ci(row.get("miou_predictable"), row.get("miou_predictable_ci")),
                number(row.get("miou_cap")),
                ", ".join(row.get("unpredictable_present") or []) or "none",
            ]
        )
    header = ["bin", "mIoU, all classes", "mIoU, predictable", "mIoU cap", "unpredictable present"]
    return lines + md_table(header, rows)


def subset_section(report: dict[str, Any]) -> list[str]:
    """mIoU over the classes of ``--classes``, beside mIoU over all classes, per row."""
    chosen = report["source"].get("classes_subset")
    if not chosen or "miou_classes" not in report["overall"]:
        return []
    lines = [f"## mIoU over {', '.join(chosen)}", ""]
    rows = [
        [row["name"], with_ci(row["miou"], row.get("miou_ci")),
         with_ci(row.get("miou_classes"), row.get("miou_classes_ci"))]
        for row in [*report["bins"], {**report["overall"], "name": "**overall**"}]
    ]  # fmt: skip
    return lines + md_table(["bin", "mIoU, all classes", "mIoU, chosen classes"], rows)


def _fraction_cell(entry: dict[str, Any] | None) -> str:
    if not entry or entry.get("closed") is None:
        return "–"
    return with_ci(entry["closed"], entry.get("closed_ci"), 2)


def gap_closed_lines(closed: dict[str, Any] | None) -> list[str]:
    """``compare.md``'s gap-closed tables: per bin, and per class (overall)."""
    if not closed:
        return []
    source, oracle = closed["source"], closed["oracle"]
    lines = [f"## Gap closed: (adapted − {source}) / ({oracle} − {source})", ""]
    for note in closed.get("notes", []):
        lines.append(f"- {note}")
    if closed.get("notes"):
        lines.append("")
    for entry in closed["adapted"]:
        name = entry["report"]
        lines += [
            f"**{name}**, mIoU over all classes (1 = the oracle's, 0 = the source-only "
            "model's; intervals: the same clusters resampled for all three):",
            "",
        ]
        rows = [
            [b["name"], number(b.get("oracle_gap"), 3), _fraction_cell(b)]
            for b in [*entry["bins"], {**entry["overall"], "name": "**overall**"}]
        ]
        lines += md_table(["bin", f"{oracle} − {source} (mIoU)", "gap closed"], rows)
        if entry.get("predictable"):
            p = entry["predictable"]
            lines += [
                f"Over the predictable classes ({', '.join(p['classes'])}): gap closed "
                f"{_fraction_cell(p)}.",
                "",
            ]
        rows = [
            [c, number(v.get("oracle_gap"), 3), _fraction_cell(v)]
            for c, v in entry["classes"].items()
        ]
        lines += ["Per class (IoU over all images):", ""]
        lines += md_table(["class", f"{oracle} − {source} (IoU)", "gap closed"], rows)
    return lines


def predictable_gap_lines(comp: dict[str, Any], baseline: str) -> list[str]:
    """``compare.md``: the gap over the predictable classes, apart from the all-class gap."""
    entry = comp.get("predictable")
    if not entry:
        return []

    classes: Sequence[str] = entry["classes"]
    lines = [
        f"Gap {comp['report']} − {baseline} in mIoU points over the predictable classes "
        f"only ({', '.join(classes)}), kept apart from the all-class gap above:",
        "",
    ]
    r = entry.get("resamples", 0)
    rows = [[b["name"], *gap_cell(b, r)] for b in entry["bins"]]
    rows.append(["**overall**", *gap_cell(entry["overall"], r)])
    return lines + md_table(["bin", "gap [interval]", "p-value", "interval excludes 0"], rows)
