"""diffsampler_rt: generate 2-d point sets with learned samplers (numpy + onnxruntime).

>>> import diffsampler_rt
>>> diffsampler_rt.generate("sobol_owen", 1024, seed=0).shape
(1024, 2)
"""
from .errors import DiffsamplerError, ModelFormatError, ModelNotFoundError, UnknownModelError
from .model import Model, bundled_models as list_models, generate, load

__version__ = "0.1.0"
__all__ = ["generate", "load", "list_models", "Model", "DiffsamplerError",
           "ModelFormatError", "ModelNotFoundError", "UnknownModelError"]
