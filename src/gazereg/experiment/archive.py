"""`gazereg archive RUN_FOLDER --out DEST`: a finished experiment's results without its data, small enough to
commit (under docs/), so they outlive the machine they were made on: the configuration, stage records, report,
attention figure, evaluation records and training metrics (these two compressed), each run's numerics.json
(the machines it trained on); no demonstrations, priors, GLC or checkpoints. `gazereg pool --runs` reads an archive as it reads the folder itself, so a preset split
over sittings that each start on a fresh machine is still reported as one experiment:

    gazereg experiment --preset paper --arms uniform other_episode --out runs/paper-abl-a   # sitting 1
    gazereg archive runs/paper-abl-a --out docs/records/paper-abl-a                         # commit it
    gazereg experiment --preset paper --arms baseline --out runs/paper-abl-b                # sitting 2
    gazereg archive runs/paper-abl-b --out docs/records/paper-abl-b
    gazereg pool --preset paper --arms baseline uniform other_episode \\
        --runs docs/records/paper-abl-a docs/records/paper-abl-b --out runs/paper-abl

The archive's `archive.json` names its source and the results' date (its files' own times are when they were
copied or checked out).

A pretraining folder (`gazereg pretrain --out`; `finished_pretrain.is_pretraining`) is archived the same way,
read back by `gazereg.experiment.read_pretraining`: its config.json, manifest.json, stage records, evaluation
record (compressed above GZIP_ABOVE bytes) and training metrics (compressed); no demonstrations, checkpoints
or policy weights (the policy is committed where it is used, its SHA-256 in the manifest):

    gazereg archive runs/pretrain --out docs/records/pretrain-ml45
"""

from __future__ import annotations

import argparse
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

from gazereg.experiment.finished import (
    ARCHIVE_RECORD,
    CONFIG_FILE,
    EVAL_INFO,
    METRICS_FILE,
    REPORT_FILE,
    STAGES_DIR,
    read_run,
    run_dir,
)
from gazereg.experiment.finished_pretrain import (
    EVAL_DIR,
    MANIFEST_FILE,
    TRAIN_DIR,
    is_pretraining,
    read_pretraining,
)
from gazereg.report.ids import RunId
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_dir, atomic_write_json, gz_path, write_gz_copy
from gazereg.training.numerics import NUMERICS_FILE

KEPT = (CONFIG_FILE, REPORT_FILE, "report.md", "figures/attention.png")
"""files kept as they are, when the folder has them (the other figures a report draws again)"""
COMPRESSED = (f"eval/{EVAL_INFO}", f"converge/{EVAL_INFO}")
"""files kept compressed (NAME.gz), with every training run's `train/RUN/metrics.jsonl`"""
GZIP_ABOVE = 100_000
"""a pretraining's eval/eval_info.json is kept compressed when larger than this (bytes), else as it is"""


def _stage_records(source: Path) -> list[Path]:
    """The stage records of `source`, relative to it (not the clocks of interrupted stages)."""
    return sorted(
        p.relative_to(source) for p in (source / STAGES_DIR).glob("*.json") if ".clock." not in p.name
    )


def archived_files(source: Path, runs: Sequence[RunId]) -> tuple[list[Path], list[Path]]:
    """(files kept as they are, files kept compressed), relative to `source`: see KEPT and COMPRESSED; the
    stage records too (not the clocks of interrupted stages), the training metrics of `runs` and their
    numerics records (`training.numerics`, where they have one)."""
    plain = [Path(name) for name in KEPT if (source / name).is_file()]
    plain += _stage_records(source)
    numerics = [(run_dir(source, run) / NUMERICS_FILE).relative_to(source) for run in runs]
    plain += [p for p in numerics if (source / p).is_file()]  # runs made before numerics.json have none
    squeezed = [Path(name) for name in COMPRESSED]
    squeezed += [(run_dir(source, run) / METRICS_FILE).relative_to(source) for run in runs]
    return plain, [
        p for p in dict.fromkeys(squeezed) if (source / p).is_file() or gz_path(source / p).is_file()
    ]


def pretraining_files(source: Path, gzip_above: int = GZIP_ABOVE) -> tuple[list[Path], list[Path]]:
    """(files kept as they are, files kept compressed), relative to the pretraining folder `source`:
    config.json, manifest.json, the stage records and train/numerics.json (where training recorded it) as
    they are; eval/eval_info.json as it is up to
    `gzip_above` bytes, else compressed (kept compressed when `source` is an archive that has it so); and
    train/metrics.jsonl compressed. Nothing else: no demonstrations, checkpoints or policy weights."""
    plain = [Path(CONFIG_FILE), Path(MANIFEST_FILE), *_stage_records(source)]
    if (source / TRAIN_DIR / NUMERICS_FILE).is_file():  # the machines it trained on (training.numerics)
        plain.append(Path(TRAIN_DIR) / NUMERICS_FILE)
    info = Path(EVAL_DIR) / EVAL_INFO
    squeezed = [Path(TRAIN_DIR) / METRICS_FILE]
    if (source / info).is_file() and (source / info).stat().st_size <= gzip_above:
        plain.append(info)
    else:
        squeezed.insert(0, info)
    return plain, [p for p in squeezed if (source / p).is_file() or gz_path(source / p).is_file()]


def archive(source: Path, dest: Path, gzip_above: int = GZIP_ABOVE) -> Path:
    """Write the archive of the finished experiment or pretraining (`is_pretraining`) in `source` to `dest`
    (whole or not at all; an existing archive there is replaced); returns `dest`. UsageError when `source` has
    not finished or `dest` is in it. `gzip_above`: see `pretraining_files`."""
    if is_pretraining(source):  # refuses an unfinished folder, naming the first unfinished stage
        date = read_pretraining(source).date
        plain, squeezed = pretraining_files(source, gzip_above)
    else:
        run = read_run(source)  # refuses an unfinished folder, naming the first unfinished stage
        date = run.date
        plain, squeezed = archived_files(source, run.runs)
    if dest.resolve() == source.resolve() or source.resolve() in dest.resolve().parents:
        raise UsageError(f"--out {dest} is inside the run folder {source}: choose a folder outside it")
    _write(source, dest, plain, squeezed, date)
    return dest


def _write(source: Path, dest: Path, plain: list[Path], squeezed: list[Path], date: str) -> None:
    """Copy `plain` and compress `squeezed` (relative to `source`) into `dest`, with the archive's record of
    its source and `date`; whole or not at all."""
    with atomic_dir(dest) as tmp:
        for rel in plain:
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source / rel, tmp / rel)
        for rel in squeezed:
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            if (source / rel).is_file():
                write_gz_copy(source / rel, gz_path(tmp / rel))
            else:  # an archive of an archive
                shutil.copyfile(gz_path(source / rel), gz_path(tmp / rel))
        atomic_write_json(tmp / ARCHIVE_RECORD, {"source": str(source), "date": date})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="gazereg archive", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "run", type=Path, help="a finished experiment's run folder, or a finished pretraining folder"
    )
    parser.add_argument("--out", type=Path, required=True, help="the archive folder to write")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if not args.run.is_dir():
        raise UsageError(f"{args.run} is not a folder")
    dest = archive(args.run, args.out)
    files = [p for p in dest.rglob("*") if p.is_file()]
    size = sum(p.stat().st_size for p in files)
    print(f"archived {args.run} into {dest}: {len(files)} files, {size / 1e3:.0f} kB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
