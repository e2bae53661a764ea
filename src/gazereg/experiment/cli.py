"""`gazereg experiment [--preset NAME] [--data-from FOLDER] [--dotted.flags ...]`: run (or resume) an experiment
into `--out` and print its report (stages: `gazereg.experiment.runner`; `--data-from`:
`gazereg.experiment.reuse`)."""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

from gazereg.experiment import reuse
from gazereg.experiment.config import DEFAULT_PRESET, PRESETS
from gazereg.experiment.preflight import preflight
from gazereg.experiment.runner import Experiment
from gazereg.experiment.runner import __doc__ as RUNNER_DOC
from gazereg.runtime.config import parse_named


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    source, args = reuse.take_data_from(sys.argv[1:] if argv is None else argv)
    description = f"{RUNNER_DOC}\n{reuse.__doc__}"
    preset, cfg = parse_named(
        PRESETS, args, prog="gazereg experiment", description=description, default=DEFAULT_PRESET
    )
    t0 = time.perf_counter()
    preflight(cfg)  # before --data-from copies anything
    if source is not None:
        reuse.reuse_data(cfg, preset, source)
    Experiment(cfg, preset).run(check=False)
    print((Path(cfg.out) / "report.md").read_text())
    print(
        f"experiment finished in {(time.perf_counter() - t0) / 60:.1f} min; report: {Path(cfg.out) / 'report.md'}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
