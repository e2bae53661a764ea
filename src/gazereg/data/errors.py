"""The errors of the data package's readers and writers (the `gazereg import` commands turn both into exit
status 1 with the message on stderr)."""

from __future__ import annotations


class DataImportError(ValueError):
    """A source file is corrupt, inconsistent or not what the importer was asked to read.

    The message names the file and the episode."""


class DataExportError(ValueError):
    """An export cannot be written as asked (no priors, maps of different sizes, an episode map that is not
    one-to-one), or a file read back as an export is not one."""
