"""The errors of the data package's readers and writers.

`DataImportError` and `DataExportError` are failures (the `gazereg` command exits with status 1 and the
message on stderr): a source file that is corrupt, inconsistent or not what it should be. Their `...UsageError`
subclasses are user mistakes (status 2): an option that names something the data set does not have, a path
that does not exist, options that contradict each other.
"""

from __future__ import annotations

from gazereg.runtime.errors import UsageError


class DataImportError(ValueError):
    """A source file is corrupt, inconsistent or not what the importer was asked to read.

    The message names the file and the episode."""


class DataExportError(ValueError):
    """An export cannot be written as asked (no priors, maps of different sizes, an episode map that is not
    one-to-one), or a file read back as an export is not one."""


class ImportUsageError(UsageError, DataImportError):
    """An import asked for something wrong: a missing file, a camera or episode the data set lacks, options
    that contradict each other."""


class ExportUsageError(UsageError, DataExportError):
    """An export asked for something wrong (an unreadable episode map, a prior the store lacks)."""
