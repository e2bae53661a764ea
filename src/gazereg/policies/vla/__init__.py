"""The reference VLA policy: configuration, model and input processing."""

from gazereg.policies.vla.configuration_vla import PRESETS, VLAConfig
from gazereg.policies.vla.modeling_vla import VLAPolicy
from gazereg.policies.vla.processor_vla import Tokenizer

__all__ = ["PRESETS", "Tokenizer", "VLAConfig", "VLAPolicy"]
