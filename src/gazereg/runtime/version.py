"""The package version (one place; `gazereg --version`, prior manifests and the package metadata read it)."""

__version__ = "0.1.0"
