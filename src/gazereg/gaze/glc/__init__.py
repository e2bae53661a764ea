"""GLC egocentric gaze estimator (Lai et al.): model, checkpoint loading, metrics and training.

>>> from gazereg.gaze.glc import GLC, GLCConfig
>>> model = GLC(GLCConfig.small()).eval()
"""

from gazereg.gaze.glc.model import GLC, GLCConfig, frame_softmax, prepare_clip

__all__ = ["GLC", "GLCConfig", "frame_softmax", "prepare_clip"]
