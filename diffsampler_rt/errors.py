"""Typed errors. Bad arguments raise plain ValueError/TypeError (as scipy.stats.qmc does);
problems with a model raise these, which also subclass the matching built-in."""


class DiffsamplerError(Exception):
    """Base class of the errors raised for models."""


class UnknownModelError(DiffsamplerError, ValueError):
    """A model name that is neither bundled nor an existing file."""


class ModelNotFoundError(DiffsamplerError, FileNotFoundError):
    """A path to an ``.onnx`` file that does not exist."""


class ModelFormatError(DiffsamplerError, ValueError):
    """A file that is not a readable ONNX model or lacks a valid diffsampler model card."""
