"""Progress measures of evaluation episodes, outcomes that move before success does: the closest approach of
the object to its target (Meta-World's `min_distance`, metres) and the furthest stage of a staged task reward
(Gym-Aloha's `max_reward`, 0..4), each a report section {table, paired, seed_level} and its markdown.

    section = stage_section(episodes, controls)     # {"stage": {...}} when the records carry max_reward, else {}
    lines = measure_lines(report, ["clean"], "stage")
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from gazereg.report.comparisons import comparison_lines, unit_level_table
from gazereg.report.tables import distance_table, paired_distance_tests


@dataclass(frozen=True)
class Measure:
    """A per-episode progress measure: the evaluation records' key (`record_key`) and how the report's section
    of it (`report[key]`: table, paired, seed_level) is shown: its heading, what it is, its unit and digits."""

    record_key: str
    heading: str
    what: str
    unit: str
    digits: int


MEASURES = {
    "distance": Measure(
        "min_distance",
        "Closest approach to the target (metres; lower is better)",
        "Per episode, the smallest distance of the object (the hand, for reach) to its target that the "
        "simulator measured: a continuous outcome that moves before success does.",
        "metres",
        4,
    ),
    "stage": Measure(
        "max_reward",
        "Furthest stage reached (the task's staged reward; higher is better)",
        "Per episode, the highest staged reward the simulator gave (Gym-Aloha: 1 touched, 2 lifted or both "
        "grasped, 3 handed over or peg against socket, 4 success): how far an episode got, also when it failed.",
        "stages",
        2,
    ),
}
"""the progress measures a report may hold, by their report key"""


def measure_lines(report: dict[str, Any], conds: list[str], key: str = "distance") -> list[str]:
    """The table of the progress measure `key` (`MEASURES`) and its paired comparisons, when the report has
    them."""
    section, m = report.get(key), MEASURES[key]
    if not section or not section.get("table"):
        return []
    d = m.digits
    lines = ["", f"## {m.heading}", "", f"{m.what} Mean [95% interval]:", ""]
    lines += ["| arm | " + " | ".join(conds) + " |", "|---|" + "---|" * len(conds)]
    for a, row in section["table"].items():
        cells = [
            f"{row[c]['mean']:.{d}f} [{row[c]['ci95'][0]:.{d}f}, {row[c]['ci95'][1]:.{d}f}]"
            if c in row
            else "-"
            for c in conds
        ]
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
    if section.get("paired"):
        lines.append("")
        lines += comparison_lines(
            section["paired"],
            ["pairs", "mean difference [95% interval]", "permutation p"],
            lambda a, b, v: [
                str(v["n"]),
                f"{v['mean_diff']:+.{d}f} [{v['ci95'][0]:+.{d}f}, {v['ci95'][1]:+.{d}f}]",
                f"{v['p_value']:.4f}",
            ],
            label="comparison",
        )
    if section.get("seed_level"):
        lines += ["", f"The same comparisons with the training seed as the unit ({m.unit}):", ""]
        lines += unit_level_table(section["seed_level"], "seed", digits=d)
    return lines


def stage_section(
    episodes: list[dict[str, Any]], controls: dict[str, list[dict[str, Any]]]
) -> dict[str, Any]:
    """{"stage": {"table", "paired"}} of the episodes' staged reward (`MEASURES["stage"]`: per arm and
    condition, and each arm against the baseline and the gaze arm against each control in `controls`, {control:
    the gaze arm's and its records}), or {} when no record carries one (a simulator without a staged reward)."""
    key = MEASURES["stage"].record_key
    table = distance_table(episodes, key)
    if not table:
        return {}
    paired = paired_distance_tests(episodes, key)
    for control, records in controls.items():
        paired.update(paired_distance_tests(records, key, reference=control))
    return {"stage": {"table": table, "paired": paired}}
