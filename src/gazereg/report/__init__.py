"""The experiment's report: run identities (`ids`), tables and tests (`tables`), the convergence analysis
(`convergence`), figures (`figures`), the assembled report (`build`), report.md and results blocks (`markdown`,
with `sections`). Every number comes from the experiment's own records."""

from gazereg.report.build import ReportSpec, StageOutputs, build_report, write_report
from gazereg.report.convergence import ConvergencePoint, checkpoint_tally, convergence, convergence_report
from gazereg.report.figures import plot_attention, plot_convergence, plot_success
from gazereg.report.ids import RunId
from gazereg.report.markdown import (
    fmt_cell,
    headline_lines,
    markdown,
    measure_lines,
    results_block,
)
from gazereg.report.tables import (
    distance_table,
    distance_value,
    machine_summary,
    overlap,
    paired_distance_tests,
    paired_tests,
    per_seed_table,
    per_task_paired_tests,
    run_of,
    success_table,
    unit_level_tests,
    verdict,
)

__all__ = [
    "ConvergencePoint",
    "ReportSpec",
    "RunId",
    "StageOutputs",
    "build_report",
    "checkpoint_tally",
    "convergence",
    "convergence_report",
    "distance_table",
    "distance_value",
    "fmt_cell",
    "headline_lines",
    "measure_lines",
    "machine_summary",
    "markdown",
    "overlap",
    "paired_distance_tests",
    "paired_tests",
    "per_seed_table",
    "per_task_paired_tests",
    "plot_attention",
    "plot_convergence",
    "plot_success",
    "results_block",
    "run_of",
    "success_table",
    "unit_level_tests",
    "verdict",
    "write_report",
]
