"""What a results block carries for programs to read, and the rule by which two blocks' numbers agree.

A results block (`markdown.results_block`) ends with one HTML comment line, invisible on the rendered page:

    <!-- results:data {"numerics": {...} or null, "success": {arm: {condition: [successes, n]}},
                       "alignment": {arm: {metric: value}}} -->

`BlockData.of_report(report).line()` renders it from report.json and `BlockData.read(block)` reads it back, so
that scripts/update_results.py --check compares counts and keys, never prose tables. "numerics" is the
`NumericsKey` of the machine and precision the runs trained with (null where the report does not record
one, or where its runs trained on machines whose keys differ: the line then also holds "machines", the
distinct keys they recorded, absent otherwise); "alignment" holds the block's attention-vs-gaze columns
rounded to ALIGNMENT_DECIMALS.

`agreement(page, run)` is the check for runs whose numerics differ (the rule, in full, in its docstring).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

from gazereg.evaluation.stats import fisher_exact
from gazereg.runtime.hardware import NumericsKey

DATA_PREFIX = "<!-- results:data "
DATA_SUFFIX = " -->"
ALIGNMENT_DECIMALS = 4
FAMILY_ALPHA = 0.01
"""the chance, when the two runs' policies succeed equally often, that `agreement` fails some cell (at most:
each of the m cells is tested at FAMILY_ALPHA / m, Bonferroni)"""

Counts = tuple[int, int]
"""(successes, episodes)"""


@dataclass(frozen=True)
class BlockData:
    """A results block's machine-readable numbers: the run's numerics key (None: not recorded), the success
    counts {arm: {condition: (successes, n)}} and the attention columns {arm: {metric: value}}."""

    numerics: NumericsKey | None
    success: dict[str, dict[str, Counts]]
    alignment: dict[str, dict[str, float]] = field(default_factory=dict)
    machines: tuple[NumericsKey, ...] = ()
    """with numerics None: the distinct keys the runs recorded when they trained (several machines, or some
    runs unrecorded); empty otherwise"""

    @classmethod
    def of_report(cls, report: dict[str, Any], metrics: tuple[str, ...] = ()) -> BlockData:
        """The data of report.json's block: its machine's "numerics" (with none, the keys its runs recorded,
        "trained_on"), every arm x condition count of its success table, and `metrics` of every arm's
        alignment."""
        key = report["machine"].get("numerics")
        trained = [] if key else report["machine"].get("trained_on") or []
        return cls(
            numerics=NumericsKey.from_dict(key) if key else None,
            machines=tuple(NumericsKey.from_dict(e["numerics"]) for e in trained),
            success={
                arm: {cond: (int(c["successes"]), int(c["n"])) for cond, c in conds.items()}
                for arm, conds in report["success"].items()
            },
            alignment={
                arm: {m: round(float(values[m]), ALIGNMENT_DECIMALS) for m in metrics if m in values}
                for arm, values in (report.get("alignment") or {}).items()
            },
        )

    def line(self) -> str:
        """The block's data line (no newline)."""
        data = {
            "numerics": self.numerics.to_dict() if self.numerics else None,
            "success": {arm: {c: list(kn) for c, kn in conds.items()} for arm, conds in self.success.items()},
            "alignment": self.alignment,
            **({"machines": [k.to_dict() for k in self.machines]} if self.machines else {}),
        }
        text = json.dumps(data, separators=(",", ":"))
        if "--" in text:  # would end the HTML comment early
            raise ValueError(f"a results block's data may not contain '--': {text}")
        return f"{DATA_PREFIX}{text}{DATA_SUFFIX}"

    @classmethod
    def read(cls, block: str) -> BlockData | None:
        """The data of a block's text (its data line); None when it has none (a block rendered before blocks
        carried their data). ValueError for more than one data line or one that is not this format."""
        lines = [ln for ln in block.splitlines() if ln.startswith(DATA_PREFIX)]
        if not lines:
            return None
        if len(lines) > 1 or not lines[0].endswith(DATA_SUFFIX):
            raise ValueError(f"a results block needs one data line {DATA_PREFIX}{{json}}{DATA_SUFFIX}")
        try:
            data = json.loads(lines[0][len(DATA_PREFIX) : -len(DATA_SUFFIX)])
            return cls(
                numerics=NumericsKey.from_dict(data["numerics"]) if data["numerics"] else None,
                success={
                    arm: {c: (int(kn[0]), int(kn[1])) for c, kn in conds.items()}
                    for arm, conds in data["success"].items()
                },
                alignment={
                    arm: {m: float(v) for m, v in vals.items()} for arm, vals in data["alignment"].items()
                },
                machines=tuple(NumericsKey.from_dict(k) for k in data.get("machines", [])),
            )
        except (json.JSONDecodeError, KeyError, TypeError, IndexError) as e:
            raise ValueError(
                f"the results block's data line is not readable ({e!r}): {lines[0][:200]}"
            ) from e


@dataclass(frozen=True)
class CellTest:
    """One arm x condition: the page's and the run's counts and the two-sided Fisher exact p between them."""

    arm: str
    condition: str
    page: Counts
    run: Counts
    p: float


@dataclass(frozen=True)
class Agreement:
    """What `agreement` found: each cell's test, the per-cell threshold, and every problem as one line
    (cells or counts missing on one side, different n, p below the threshold); agrees when none."""

    cells: list[CellTest]
    threshold: float
    problems: list[str]

    @property
    def agrees(self) -> bool:
        return not self.problems


def agreement(page: BlockData, run: BlockData, family_alpha: float = FAMILY_ALPHA) -> Agreement:
    """Whether `run`'s success counts agree with `page`'s up to chance, for runs whose numerics differ.

    The rule: both have the same arms, the same conditions per arm and the same number of episodes n in each
    cell; and for every arm x condition cell, the two-sided Fisher exact test between the page's k/n and the
    run's k/n gives p >= family_alpha / m, m the number of cells (Bonferroni: when every arm succeeds equally
    often under both numerics, some cell fails with chance at most family_alpha). The test treats the two
    runs as independent samples; they evaluate the same setups, which makes their counts closer than that, so
    the rule errs towards passing. The attention columns are not tested (see `alignment_differences`)."""
    problems = []
    for arm in sorted(set(page.success) ^ set(run.success)):
        problems.append(f"arm {arm} is only in the {'page' if arm in page.success else 'run'}'s block")
    pairs = []
    for arm in sorted(set(page.success) & set(run.success)):
        a, b = page.success[arm], run.success[arm]
        for cond in sorted(set(a) ^ set(b)):
            problems.append(f"{arm} x {cond} is only in the {'page' if cond in a else 'run'}'s block")
        for cond in sorted(set(a) & set(b)):
            if a[cond][1] != b[cond][1]:
                problems.append(f"{arm} x {cond}: {a[cond][1]} episodes on the page, {b[cond][1]} in the run")
            else:
                pairs.append((arm, cond, a[cond], b[cond]))
    threshold = family_alpha / max(1, len(pairs))
    cells = [CellTest(arm, cond, x, y, fisher_exact(x[0], x[1], y[0], y[1])) for arm, cond, x, y in pairs]
    problems += [
        f"{c.arm} x {c.condition}: page {c.page[0]}/{c.page[1]}, run {c.run[0]}/{c.run[1]}, Fisher exact "
        f"p = {c.p:.3g} < {threshold:.3g}"
        for c in cells
        if c.p < threshold
    ]
    return Agreement(cells, threshold, problems)


def alignment_differences(page: BlockData, run: BlockData) -> dict[str, float]:
    """{metric: the largest |page - run| over the arms and metrics both blocks have} of the attention columns.
    Reported, not tested: one run per numerics key gives no spread to judge a difference by."""
    out: dict[str, float] = {}
    for arm in set(page.alignment) & set(run.alignment):
        for metric in set(page.alignment[arm]) & set(run.alignment[arm]):
            d = abs(page.alignment[arm][metric] - run.alignment[arm][metric])
            out[metric] = max(out.get(metric, -math.inf), d)
    return dict(sorted(out.items()))
