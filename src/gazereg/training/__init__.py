"""Training helpers: checkpoints (safetensors + JSON, atomic), metric loggers, EMA."""
