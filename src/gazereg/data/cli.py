"""`gazereg import`: demonstrations from other formats into an episode store, and priors back out.

    gazereg import lerobot --root PATH --out STORE [--gaze-camera front] [--cameras front wrist]
    gazereg import hdf5 --file PATH [PATH ...] --out STORE [--rotate180 auto|none|all|cam1,cam2]
    gazereg import export-priors --store STORE --prior NAME --out DIR
    gazereg import write-gaze --store STORE --prior NAME --root DATASET --out NEW_ROOT

`lerobot` reads a LeRobot v3.0 data set (gazereg.data.formats.lerobot_v3), `hdf5` a LIBERO / robomimic HDF5 file
(gazereg.data.formats.hdf5), `export-priors` writes a store's priors as a LeRobot sidecar keyed by episode_index and
frame_index (DIR/priors.parquet + DIR/priors.json; see gazereg.data.export), `write-gaze` a new version of the
LeRobot data set the store came from, with the priors as features gaze.<camera>.heatmap / gaze.<camera>.valid.
Run a subcommand with --help for its options.

Imports stream one episode at a time and resume (gazereg.data.imports): episodes already in the store are skipped
after checking that they came from the same source with the same settings, and every episode is written
atomically.
"""

from __future__ import annotations

from gazereg.runtime.subcommands import Subcommands, run_entry_logged

COMMANDS = Subcommands(
    prog="gazereg import",
    synopsis="<lerobot|hdf5|export-priors|write-gaze> [options]",
    commands={
        "lerobot": (
            "gazereg.data.formats.lerobot_v3:import_main",
            "import a LeRobot v3.0 data set (parquet + MP4) into an episode store",
        ),
        "hdf5": (
            "gazereg.data.formats.hdf5:import_main",
            "import LIBERO / robomimic HDF5 demonstrations into an episode store",
        ),
        "export-priors": (
            "gazereg.data.export:main",
            "export a store's gaze priors as a LeRobot sidecar (parquet + JSON)",
        ),
        "write-gaze": (
            "gazereg.data.export:write_gaze_main",
            "write a new LeRobot data set version with the priors as gaze.<camera>.heatmap/.valid features",
        ),
    },
    footer=(__doc__ or "").split("\n\n")[1],
    noun="source",
)


def main(argv: list[str] | None = None) -> int:
    """Dispatch with INFO logging. Errors propagate to the `gazereg` command, which prints one line and exits
    with status 1 for a bad source file (`DataImportError`, `DataExportError`) and 2 for a usage mistake
    (`ImportUsageError`, `ExportUsageError`, a missing path)."""
    return COMMANDS.main(argv, run=run_entry_logged)


if __name__ == "__main__":
    raise SystemExit(main())
