"""diffsampler trainer: reference samplers, grid embedding, U-Net, diffusion training.

Importing ``trainer`` itself is cheap: the numpy-only parts (``trainer.samplers``,
``trainer.embedding``, ``trainer.stats``) do not import torch; the torch parts
(``trainer.unet``, ``trainer.diffusion``, ``trainer.train``) do.
"""


def fit(*args, **kwargs):
    """Learn a sampler from example point sets: :func:`trainer.fitting.run.fit` (imported on
    use, so that ``import trainer`` stays cheap)."""
    from .fitting.run import fit as _fit
    return _fit(*args, **kwargs)
