"""The reference VLA policy: configuration, model and input processing."""

from gazevla.policies.vla.configuration_vla import PRESETS, VLAConfig
from gazevla.policies.vla.modeling_vla import VLAPolicy
from gazevla.policies.vla.processor_vla import Tokenizer

__all__ = ["PRESETS", "Tokenizer", "VLAConfig", "VLAPolicy"]
