"""The InsertNeRF generator: encoder, projection, aggregation, filter, HyperNet modules, NeRF MLP, losses."""
from .insertnerf import InsertNeRF
from .types import EncodedViews, LossTerms, RenderOutput, SourceViews

__all__ = ["InsertNeRF", "SourceViews", "EncodedViews", "RenderOutput", "LossTerms"]
