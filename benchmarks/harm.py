"""Do no harm: how many accepted findings make the test J2 worse.

A finding is *accepted* when the diagnosis's verdict names an effect (a catalog effect or a
discovered one; not ``none`` or ``unexplained``). For each accepted finding the test J2 after
(the model with the finding, re-identified) is compared with the test J2 before (the base model
re-identified without it), in total and per test subset (each test recording, or each of the
paper's test sets on the real data). Targets: no accepted finding worsens the total by more than
5 %; at most 1 in 20 worsens a subset by more than 10 %.

    python benchmarks/harm.py REPORT.json [REPORT.json ...]

prints the figure for diagnosis reports (``report.json`` of ``python -m sweep.diagnose``), e.g.
the real recordings' ``docs/diagnosis-real/report.json``; :mod:`benchmarks.diagnose_planted`
prints it beside explained / named / flagged for each planted set.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: an accepted finding harms the total when it raises the test J2 total by more than this share
TOTAL_LIMIT = 0.05
#: ... and a subset when it raises the subset's test J2 by more than these shares
SUBSET_LIMITS = (0.10, 0.05)
#: verdicts that accept no finding
NO_FINDING = ("none", "unexplained")


@dataclass(frozen=True)
class Harm:
    """Counts over accepted findings: how many, how many worsen the test J2 total by more than
    5 %, how many (finding, subset) pairs there are and how many worsen by more than 10 % and
    5 %."""

    findings: int = 0
    total_worse: int = 0
    subsets: int = 0
    subset_worse_10: int = 0
    subset_worse_5: int = 0

    def __add__(self, other: Harm) -> Harm:
        return Harm(
            self.findings + other.findings,
            self.total_worse + other.total_worse,
            self.subsets + other.subsets,
            self.subset_worse_10 + other.subset_worse_10,
            self.subset_worse_5 + other.subset_worse_5,
        )

    def text(self) -> str:
        """``harm: total > 5 % 0/3, subsets > 10 % 1/12 (> 5 % 2/12)``."""
        return (
            f"harm: total > {100 * TOTAL_LIMIT:.0f} % {self.total_worse}/{self.findings}, "
            f"subsets > {100 * SUBSET_LIMITS[0]:.0f} % {self.subset_worse_10}/{self.subsets} "
            f"(> {100 * SUBSET_LIMITS[1]:.0f} % {self.subset_worse_5}/{self.subsets})"
        )


def finding_harm(verdict: str, before: Mapping[str, float], after: Mapping[str, float]) -> Harm:
    """The counts of one diagnosis: ``before`` and ``after`` are {subset: J2, "Total": J2} on the
    test recordings. No accepted finding (or no test table): nothing counted."""
    if verdict in NO_FINDING or "Total" not in before or "Total" not in after:
        return Harm()
    labels = [k for k in before if k != "Total"]
    worse = [after[k] / before[k] - 1.0 for k in labels]
    return Harm(
        findings=1,
        total_worse=int(after["Total"] / before["Total"] - 1.0 > TOTAL_LIMIT),
        subsets=len(labels),
        subset_worse_10=sum(w > SUBSET_LIMITS[0] for w in worse),
        subset_worse_5=sum(w > SUBSET_LIMITS[1] for w in worse),
    )


def total(harms: Iterable[Harm]) -> Harm:
    """The counts summed over diagnoses."""
    out = Harm()
    for h in harms:
        out = out + h
    return out


def report_harm(report: Mapping[str, Any], objective: str = "J2") -> Harm:
    """The counts of one ``report.json`` (its verdict and test tables ``J_before``, ``J_after``)."""
    before = (report.get("J_before") or {}).get(objective, {})
    after = (report.get("J_after") or {}).get(objective, {})
    return finding_harm(str(report["verdict"]), before, after)


def main(argv: list[str] | None = None) -> int:
    paths = [Path(p) for p in (sys.argv[1:] if argv is None else argv)]
    if not paths:
        print(__doc__.split("\n\n")[2].strip(), file=sys.stderr)
        return 2
    harms = []
    for path in paths:
        report = json.loads(path.read_text())
        h = report_harm(report)
        harms.append(h)
        before = (report.get("J_before") or {}).get("J2", {})
        after = (report.get("J_after") or {}).get("J2", {})
        change = ", ".join(
            f"{k} {100 * (after[k] / before[k] - 1):+.1f} %" for k in before if k in after
        )
        print(f"{path}: verdict {report['verdict']}; test J2 {change or '-'}; {h.text()}")
    if len(paths) > 1:
        print(f"all: {total(harms).text()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
