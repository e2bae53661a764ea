"""Training: `loop` (`gazereg train`), `setup` (data, policy, optimiser, resume), `config` (TrainConfig and its
presets), `schedule` (LR schedule, parameter groups, step generators), `checkpoint` (safetensors + JSON,
atomic), `ema`, `logger` (metrics.jsonl and optional external loggers); `glc*` train the GLC gaze estimator."""
