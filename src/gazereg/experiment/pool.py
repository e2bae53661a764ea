"""One report over run folders of one experiment that differ only in their training seeds and arms: a preset
too long for one sitting, run one seed per folder (each folder a whole, resumable experiment), or extra arms
run later on the same setups (ablations), then reported as one.

    gazereg experiment --preset paper --train-seeds 0 --out runs/paper-s0      # one sitting each
    gazereg experiment --preset paper --train-seeds 1 --out runs/paper-s1 --data-from runs/paper-s0
    gazereg experiment --preset paper --train-seeds 2 --out runs/paper-s2 --data-from runs/paper-s0
    gazereg pool --preset paper --runs runs/paper-s0 runs/paper-s1 runs/paper-s2 --out runs/paper
    gazereg experiment --preset paper --arms uniform --out runs/paper-uniform --data-from runs/paper-s0  # later
    gazereg pool --preset paper --arms baseline gaze glc perturbed location uniform \
        --runs runs/paper-s0 runs/paper-s1 runs/paper-s2 runs/paper-uniform --out runs/paper-ablations

The pooled report is the one `gazereg experiment --preset paper --out runs/paper` would write from the same
records: every folder must hold a finished experiment of the configuration given (`--out`, its seeds and arms
aside, and the execution keys, which change how a run ran, not what it measured), each run (arm x seed) of
`--arms` x `--train-seeds` must be in exactly one folder, and the folders' demonstrations and GLC records must
be the same (each folder collects and trains them from the same seeds, or copies them with `--data-from`,
`gazereg.experiment.reuse`). Its wall time is the folders' summed.

Demonstrations collected again in each folder from the same seeds are the same on one machine, but an expert's
episode can end a step earlier or later on another CPU (its floating point differs): `--demos-across-machines`
pools folders whose demonstrations differ in their frame counts only (the same episodes per task), and the
report names each folder's frames; anything else that differs is refused with or without it.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from gazereg.experiment.config import EXECUTION_KEYS, PRESETS, ExperimentConfig
from gazereg.experiment.finished import CONFIG_FILE, POOLED_RECORD, read_run
from gazereg.experiment.records import report_spec
from gazereg.experiment.runner import Experiment
from gazereg.report.build import StageOutputs, build_report, write_report
from gazereg.report.figures import stack_figures
from gazereg.report.ids import RunId
from gazereg.runtime.config import config_diff, parse_named, save_config, to_dict
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_write_json

ACROSS_MACHINES = "--demos-across-machines"


def source_outputs(cfg: ExperimentConfig, preset: str, source: Path) -> tuple[list[RunId], StageOutputs]:
    """(the runs, the stage outputs) of the finished experiment in `source`, refused (UsageError naming the
    differing keys) when it ran another configuration than `cfg` apart from its seeds and arms."""
    exp = Experiment(cfg, preset).sibling(source, "--runs")
    unknown = [a for a in exp.cfg.arms if a not in cfg.arms]
    if unknown:
        raise UsageError(f"--runs: {source} trained {unknown}, not in --arms {list(cfg.arms)}")
    run = read_run(source)
    return list(run.runs), run.stage_outputs()


def merge_outputs(
    sources: Sequence[Path], outputs: Sequence[StageOutputs], out: Path, across_machines: bool = False
) -> StageOutputs:
    """The outputs of the pooled runs as one experiment's: records and per-run values together, the same
    demonstrations and GLC (refused otherwise; with `across_machines`, demonstrations that differ in frames
    only, their record then naming each folder's, "frames_per_folder"), one attention figure in `out`
    stacking the folders' that show arms not shown above them (each folder's figure shows its own arms), the
    latest date and the stage times summed."""
    first = outputs[0]
    glcs = [(source, o.glc) for source, o in zip(sources, outputs) if o.glc is not None]
    frames = [o.demos.get("frames") for o in outputs]
    for source, o in zip(sources[1:], outputs[1:]):
        if _demos(o.demos) == _demos(first.demos):
            continue
        if not (across_machines and _demos(o.demos, "frames") == _demos(first.demos, "frames")):
            hint = "" if across_machines else " (--demos-across-machines: when only their frames differ)"
            raise UsageError(
                f"--runs: {source}'s demonstrations differ from {sources[0]}'s: not one experiment{hint}"
            )
    demos = first.demos if len(set(frames)) == 1 else {**first.demos, "frames_per_folder": frames}
    for source, glc in glcs[1:]:
        if _comparable(glc) != _comparable(glcs[0][1]):
            raise UsageError(f"--runs: {source}'s GLC differs from {glcs[0][0]}'s: not one experiment")
    figure = Path("figures") / "attention.png"
    stack_figures(attention_sources(sources, outputs), out / figure)
    times: dict[str, float] = {}
    for o in outputs:
        for stage, seconds in o.stage_times.items():
            times[stage] = times.get(stage, 0.0) + seconds
    return StageOutputs(
        episodes=[r for o in outputs for r in o.episodes],
        checkpoint_episodes=[r for o in outputs for r in o.checkpoint_episodes],
        demos=demos,
        glc=glcs[0][1] if glcs else None,
        final_metrics={k: v for o in outputs for k, v in o.final_metrics.items()},
        metrics_files={k: v for o in outputs for k, v in o.metrics_files.items()},
        alignment={k: v for o in outputs for k, v in o.alignment.items()},
        attention_figure=figure.as_posix(),
        date=max(o.date for o in outputs),
        stage_times=times,
        numerics={k: v for o in outputs for k, v in o.numerics.items()},
    )


def attention_sources(sources: Sequence[Path], outputs: Sequence[StageOutputs]) -> list[Path]:
    """The first folder's attention figure and those of the later folders, in order, that show an arm no
    earlier one shows (a folder's figure shows each arm its align stage aligned, at its first training seed)."""
    shown: set[str] = set()
    figures = []
    for source, o in zip(sources, outputs):
        arms = {run.arm for run in o.alignment}
        if not figures or arms - shown:
            figures.append(source / o.attention_figure)
            shown |= arms
    return figures


def _demos(record: dict, *also: str) -> object:
    """A demonstrations record as `_comparable` has it, an empty "without" (no task left undemonstrated) the
    same as none (records written before the key existed)."""
    return _comparable({k: v for k, v in record.items() if k != "without" or v}, *also)


def _comparable(record: object, *also: str) -> object:
    """A stage record without what differs between folders of one experiment: durations (`seconds`) and the
    paths of the GLC checkpoints each folder trained or copied (`checkpoint`), and the keys `also`."""
    drop = ("seconds", "checkpoint", *also)
    if isinstance(record, dict):
        return {k: _comparable(v, *also) for k, v in record.items() if k not in drop}
    if isinstance(record, list):
        return [_comparable(v, *also) for v in record]
    return record


def preset_flags(cfg: ExperimentConfig, preset: str) -> list[str]:
    """The options that make preset `preset` into `cfg`, what was measured only (the output folder, arms,
    training seeds and execution keys aside), e.g. ["--train.policy.chunk", "4"]: a pooled report's command
    names them, so that it pools the same folders again."""
    ignore = ("out", "arms", "train_seeds", "train.run_dir", *EXECUTION_KEYS)
    flags: list[str] = []
    for key, (_, value) in config_diff(to_dict(PRESETS[preset]()), to_dict(cfg), ignore).items():
        flags += [f"--{key.replace('_', '-')}", *map(str, value if isinstance(value, list) else [value])]
    return flags


def pool(cfg: ExperimentConfig, preset: str, sources: Sequence[Path], across_machines: bool = False) -> Path:
    """Write the pooled report of `sources` into `cfg.out` (report.json, report.md, figures, the config and
    pooled.json naming the folders); returns report.md's path. `across_machines`: `merge_outputs`'s."""
    if not sources:
        raise UsageError("--runs needs the run folders to pool")
    runs, outputs = zip(*(source_outputs(cfg, preset, Path(s)) for s in sources))
    flat = [str(r) for group in runs for r in group]
    if len(set(flat)) != len(flat):
        raise UsageError(f"--runs: the folders' runs overlap ({', '.join(sorted(flat))}); each run once")
    wanted = sorted(str(RunId(a, s)) for a in cfg.arms for s in cfg.train_seeds)
    if sorted(flat) != wanted:
        missing, extra = sorted(set(wanted) - set(flat)), sorted(set(flat) - set(wanted))
        raise UsageError(
            f"--runs: the folders' runs are not --arms x --train-seeds: missing {', '.join(missing) or 'none'}, "
            f"not asked for {', '.join(extra) or 'none'}"
        )
    out = Path(cfg.out)
    if any(out.resolve() == Path(s).resolve() for s in sources):
        raise UsageError(f"--out {out} is one of the pooled folders: choose another")
    out.mkdir(parents=True, exist_ok=True)
    merged = merge_outputs([Path(s) for s in sources], outputs, out, across_machines)
    report = build_report(report_spec(cfg, preset), merged, out)
    report["pooled_from"] = [str(s) for s in sources]
    needed = "frames_per_folder" in merged.demos  # the flag in the command only where the pool needs it
    report["pooled_flags"] = [*([ACROSS_MACHINES] if needed else []), *preset_flags(cfg, preset)]
    save_config(cfg, out / CONFIG_FILE)
    atomic_write_json(
        out / POOLED_RECORD, {"folders": report["pooled_from"], "runs": [list(map(str, g)) for g in runs]}
    )
    return write_report(out, report)


def take_runs(argv: Sequence[str]) -> tuple[list[Path], list[str]]:
    """Remove `--runs DIR [DIR ...]` (the values up to the next option) from argv: (the folders, the rest)."""
    rest, runs, taking = [], [], False
    for arg in argv:
        if arg == "--runs":
            taking = True
        elif taking and not arg.startswith("--"):
            runs.append(Path(arg))
        else:
            taking = False
            rest.append(arg)
    return runs, rest


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    sources, rest = take_runs(args)
    across = ACROSS_MACHINES in rest
    rest = [a for a in rest if a != ACROSS_MACHINES]
    preset, cfg = parse_named(PRESETS, rest, prog="gazereg pool", description=__doc__ or "", required=True)
    path = pool(cfg, preset, sources, across)
    print(path.read_text())
    print(f"pooled {len(sources)} runs into {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
