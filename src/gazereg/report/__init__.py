"""The experiment's report: tables and tests (`tables`), figures (`figures`), report.md and README blocks
(`markdown`). Every number comes from the experiment's own records."""

from gazereg.report.figures import plot_attention, plot_convergence, plot_success
from gazereg.report.markdown import (
    distance_lines,
    fmt_cell,
    markdown,
    readme_block,
    replace_block,
    update_readme,
)
from gazereg.report.tables import (
    base_arm,
    convergence,
    distance_table,
    machine_summary,
    overlap,
    paired_distance_tests,
    paired_tests,
    per_seed_table,
    success_table,
    verdict,
)

__all__ = [
    "base_arm",
    "convergence",
    "distance_lines",
    "distance_table",
    "fmt_cell",
    "machine_summary",
    "markdown",
    "overlap",
    "paired_distance_tests",
    "paired_tests",
    "per_seed_table",
    "plot_attention",
    "plot_convergence",
    "plot_success",
    "readme_block",
    "replace_block",
    "success_table",
    "update_readme",
    "verdict",
]
