"""Learning a sampler from a user's own example point sets (``python -m trainer fit``).

Data flows one way: :mod:`.examples` (read and check the files) -> :mod:`.analysis`
(embedding, uniformity, structure, asserted invariances) -> :mod:`.data` (held-out split,
embedded pools) -> the trainer -> export -> :mod:`.calibrate` (finishing steps from the
held-in sets) -> :mod:`.evaluate` / :mod:`.report` (against the held-out sets).
"""
from .examples import ExampleError, read_examples
from .run import FitResult, fit

__all__ = ["fit", "FitResult", "read_examples", "ExampleError"]
