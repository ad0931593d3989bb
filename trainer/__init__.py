"""diffsampler trainer: reference samplers, grid embedding, U-Net, diffusion training.

Importing ``trainer`` itself is cheap: the numpy-only parts (``trainer.samplers``,
``trainer.embedding``, ``trainer.stats``) do not import torch; the torch parts
(``trainer.unet``, ``trainer.diffusion``, ``trainer.train``) do.
"""
