"""GLC egocentric gaze estimator (Lai et al.): model, checkpoint loading, metrics and training.

>>> from gazevla.glc import GLC, GLCConfig
>>> model = GLC(GLCConfig.small()).eval()
"""

from gazevla.glc.model import GLC, GLCConfig, frame_softmax, prepare_clip

__all__ = ["GLC", "GLCConfig", "frame_softmax", "prepare_clip"]
