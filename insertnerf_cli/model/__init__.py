"""The InsertNeRF generator: encoder, projection, aggregation, filter, HyperNet modules, NeRF MLP, losses."""
from insertnerf_cli.model.insertnerf import InsertNeRF
from insertnerf_cli.model.types import EncodedViews, LossTerms, RenderOutput, SourceViews

__all__ = ["InsertNeRF", "SourceViews", "EncodedViews", "RenderOutput", "LossTerms"]
