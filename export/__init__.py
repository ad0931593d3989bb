"""Export trained checkpoints to self-contained ONNX files that carry their model card."""
from .onnx_export import export_checkpoint, export_model, model_card
from .parity import ParityError, check_parity

__all__ = ["export_checkpoint", "export_model", "model_card", "check_parity", "ParityError"]
