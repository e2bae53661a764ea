"""Episode store and importers/exporters."""

from gazevla.data.store import Episode, EpisodeStore

__all__ = ["Episode", "EpisodeStore"]
