"""Progress measures of evaluation episodes, outcomes that move before success does: the closest approach of
the object to its target (Meta-World's `min_distance`, metres) and the furthest stage of a staged task reward
(Gym-Aloha's `max_reward`, 0..4), each a report section {table, paired, seed_level} and its markdown.

    sections = progress_sections(episodes, controls)   # {"distance": {...}, "stage": {...} if max_reward}
    lines = measure_lines(report, ["clean"], "stage")
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from gazereg.report.comparisons import comparison_lines, unit_level_table
from gazereg.report.tables import distance_table, distance_value, paired_distance_tests, unit_level_tests


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


def measure_section(
    episodes: list[dict[str, Any]], controls: dict[str, list[dict[str, Any]]], key: str
) -> dict[str, Any]:
    """The report section of the progress measure `key` (`MEASURES`): its table per arm and condition, each
    arm against the baseline and the gaze arm against each control in `controls` ({control: the gaze arm's and
    its records}) paired by setup, and the same with the training seed as the unit (None when no pair of
    seeds)."""
    m = MEASURES[key].record_key
    paired = paired_distance_tests(episodes, m)
    seeds = unit_level_tests(episodes, "seed", value=distance_value(m))
    for control, records in controls.items():
        paired.update(paired_distance_tests(records, m, reference=control))
        seeds.update(unit_level_tests(records, "seed", control, distance_value(m)))
    return {"table": distance_table(episodes, m), "paired": paired, "seed_level": seeds or None}


def progress_sections(
    episodes: list[dict[str, Any]], controls: dict[str, list[dict[str, Any]]]
) -> dict[str, Any]:
    """The report's progress sections (`measure_section`): "distance" always (empty where the simulator
    measures none), "stage" only when the records carry a staged reward (Gym-Aloha)."""
    stage = measure_section(episodes, controls, "stage")
    return {"distance": measure_section(episodes, controls, "distance")} | (
        {"stage": stage} if stage["table"] else {}
    )
