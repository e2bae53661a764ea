"""Episode store, training data set, importers (imports, formats/) and the priors export (export)."""

from gazereg.data.store import Episode, EpisodeStore

__all__ = ["Episode", "EpisodeStore"]
