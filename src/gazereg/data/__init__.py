"""Episode store and importers/exporters."""

from gazereg.data.store import Episode, EpisodeStore

__all__ = ["Episode", "EpisodeStore"]
