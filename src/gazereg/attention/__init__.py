"""Attention probes: differentiable attention from chosen queries to one camera's patch keys."""

from gazereg.attention.probe import AttentionProbe, ProbeSpec, tap

__all__ = ["AttentionProbe", "ProbeSpec", "tap"]
