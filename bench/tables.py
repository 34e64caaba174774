"""The benchmark's table: one row a figure (figure, ours, design document, target, held)."""

from __future__ import annotations


def table(lines: list[tuple[str, str, str, str, bool | None]]) -> str:
    w = [max(len(x[i]) for x in lines) for i in range(4)]
    head = ("figure", "ours", "design doc", "target")
    text = [" | ".join(h.ljust(w[i]) for i, h in enumerate(head)) + " | held"]
    text.append("-+-".join("-" * n for n in w) + "-+-----")
    for row in lines:
        held = {True: " | yes", False: " | NO", None: " | -"}[row[4]]
        text.append(" | ".join(row[i].ljust(w[i]) for i in range(4)) + held)
    return "\n".join(text)
