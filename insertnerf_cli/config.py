"""Frozen configuration dataclasses and their JSON round trip.

Every checkpoint stores its ``ModelConfig`` as JSON; ``render`` rebuilds the network from it, so the round trip
must be exact and must refuse keys it does not know (a checkpoint from another version) with one clear line.
"""
from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

from insertnerf_cli.errors import UserError

T = TypeVar("T")

# What render, eval and finetune see of a scene by default: the long side of its photos in pixels, and how many
# of the nearest reference views condition each frame (fine-tuning at the same values is what render profits from).
DEFAULT_RESOLUTION = 256
DEFAULT_VIEWS = 10

# The generator's structures of space (ModelConfig.backbone): one NeRF field, or NeRF++'s foreground and background.
Backbone = Literal["nerf", "nerfpp"]
BACKBONES: tuple[str, ...] = typing.get_args(Backbone)


@dataclass(frozen=True)
class ModelConfig:
    """Every size and switch of the InsertNeRF generator (see docs/model.md for what each costs).

    Scales are listed coarse to fine: index 0 is the 1/8-resolution U-Net output, 1 is 1/4, 2 is 1/2.
    """

    # --- U-Net encoder
    encoder_widths: tuple[int, ...] = (16, 24, 32, 48)  # channels at 1/2, 1/4, 1/8, 1/16 of the image
    feature_dims: tuple[int, int, int] = (16, 8, 8)  # output features at 1/8, 1/4, 1/2 (paper: coarse is widest)
    backbone_decoder_width: int = 8  # the small decoder used only by the reconstruction loss
    # --- multi-layer dynamic-static aggregation
    aggregate_hidden: int = 8  # hidden width of the dynamic-weight MLP (per view, so kept small)
    static_sharpness_init: float = 0.2  # IBRNet's s in exp(|s|(cos - 1))
    visibility_cue: bool = False  # each view's deviation from the others feeds its dynamic weight
    # K > 0: the reference colour weighs each view by its dynamic weight times the unstructured-lumigraph prior
    # over the K views whose rays through the sample are closest in angle to the query ray (aggregate.py); 0: by
    # the dynamic weight alone.
    colour_prior_views: int = 0
    # K > 0: each sample aggregates at most the K reference views whose rays through it are closest in angle to
    # the query ray (projection.nearest_in_angle); 0: every view. A render asked for more views than training
    # drew then still feeds the aggregator statistics over a training-like count, chosen per sample.
    sample_views: int = 0
    # Photo-consistency (model/consistency.py): T > 0 multiplies a pass's compositing weights by
    # exp(-v / T), v the variance of the reference colours under the lumigraph prior of ``consistency_views`` K
    # (the K-1 views nearest in angle), so the weight moves to the depths where the views agree (a plane-sweep
    # cue, no parameters); 0: off.
    consistency_temperature_coarse: float = 0.0
    consistency_temperature_fine: float = 0.0
    consistency_views: int = 4
    # --- HyperNet modules and the NeRF MLP
    nerf_width: int = 32
    nerf_layers: int = 4  # geometry layers, each preceded by a HyperNet module
    appearance_width: int = 32
    z_branches: int = 2  # progressive appearance hyper branches (paper Table 9: 2 is the sweet spot)
    film_hidden: int = 16  # hidden width of the per-sample bias / DFiLM frequency and shift MLP
    filter_nodes: int = 8  # rank of the sampling-aware filter's adjacency over the samples of a ray
    conditioning: Literal["hyper", "concat"] = "hyper"  # "concat": the feature-concatenation ablation
    # --- sampling and encodings
    samples_coarse: int = 64
    samples_fine: int = 64
    separate_fine_head: bool = False  # False: both passes share one head (needs samples_coarse == samples_fine)
    sample_in_disparity: bool = False  # coarse samples uniform in 1/t (forward-facing) instead of in t
    pe_freqs_pos: int = 6
    pe_freqs_dir: int = 4
    coord_scale: float = 0.5  # world coordinates are multiplied by this before positional encoding
    num_views: int = 8  # reference views N used in training
    # --- rendering
    density_activation: Literal["softplus", "relu", "exp"] = "softplus"
    density_bias: float = -1.0  # added before the activation so an untrained field starts mostly empty
    blend_reference_colour: bool = True  # mix the network colour with the dynamic-weight blend of reference colours
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    # What a ray sees past its far bound: the reference views' colours where they see the ray's direction at
    # infinity, aggregated like any sample; ``background`` then only fills rays no view sees there.
    infinity_sample: bool = False
    # --- backbone (docs/method.md, The NeRF++ backbone): "nerf" one field over [near, far]; "nerfpp" NeRF++'s
    # foreground field inside a sphere about the world's origin (the subject, after scene normalisation) that holds
    # the reference cameras, ``foreground_margin`` times as wide as the farthest of them, and a background field
    # over inverted-sphere coordinates out to infinity, with ``samples_background`` samples per ray.
    backbone: Backbone = "nerf"
    samples_background: int = 16
    foreground_margin: float = 1.1
    # --- loss weights (docs/method.md, Training)
    loss_backbone_weight: float = 0.1
    loss_dynamic_weight: float = 1.0
    # geometry supervision (model/geometry_losses.py): exact synthetic depth and mip-NeRF 360's distortion
    loss_depth_weight: float = 0.0
    loss_distortion_weight: float = 0.0

    def __post_init__(self) -> None:
        check_field_types(self)  # also the choices of the Literal fields and finite floats
        if len(self.feature_dims) != 3 or len(self.encoder_widths) != 4:
            raise ValueError("feature_dims needs 3 scales and encoder_widths 4 levels")
        _at_least(self, 1, "encoder_widths", "feature_dims", "backbone_decoder_width", "aggregate_hidden",
                  "nerf_width", "nerf_layers", "appearance_width", "z_branches", "film_hidden", "filter_nodes",
                  "samples_coarse", "samples_fine", "num_views", "samples_background")
        _at_least(self, 0, "pe_freqs_pos", "pe_freqs_dir", "loss_backbone_weight", "loss_dynamic_weight",
                  "loss_depth_weight", "loss_distortion_weight", "colour_prior_views",
                  "sample_views", "consistency_temperature_coarse", "consistency_temperature_fine")
        _at_least(self, 2, "consistency_views")
        if self.foreground_margin < 1.0:
            raise ValueError(f"foreground_margin must be at least 1 (the sphere holds the cameras), got "
                             f"{self.foreground_margin}")
        if self.coord_scale <= 0 or not all(0.0 <= c <= 1.0 for c in self.background):
            raise ValueError(f"coord_scale must be positive and background colours in [0, 1], got "
                             f"coord_scale={self.coord_scale}, background={self.background}")
        if any(d % 2 for d in self.feature_dims):
            raise ValueError(f"feature_dims must be even (the aggregation halves them), got {self.feature_dims}")
        if not self.separate_fine_head and self.samples_coarse != self.samples_fine:
            raise ValueError("a shared fine head needs samples_coarse == samples_fine "
                             "(the HyperNet mixes along the sample axis); set separate_fine_head=True")


def _at_least(cfg: Any, low: float, *names: str) -> None:
    """ValueError naming every field (a number or a tuple of numbers) with a value below ``low``."""
    values = {name: getattr(cfg, name) for name in names}
    bad = [f"{n}={v}" for n, v in values.items() if min(v if isinstance(v, tuple) else (v,)) < low]
    if bad:
        raise ValueError(f"{', '.join(bad)}: must be {'positive' if low == 1 else f'at least {low:g}'}")


def check_field_types(cfg: Any) -> None:
    """ValueError unless every field of a dataclass instance has its annotated type: int (not bool), finite
    float, bool, a Literal's choice, a tuple of those (of the annotated length), None where allowed.
    A JSON file or a Python caller can put any value in a frozen dataclass; this keeps them out."""
    hints = typing.get_type_hints(type(cfg))
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if not _has_type(hints[f.name], value):
            raise ValueError(f"{f.name} must be {_type_name(hints[f.name])}, got {value!r}")


def _has_type(hint: Any, value: Any) -> bool:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Literal:
        return value in args
    if origin in (typing.Union, types.UnionType):
        return any(_has_type(a, value) for a in args)
    if origin is tuple:
        if not isinstance(value, tuple):
            return False
        arms = [args[0]] * len(value) if len(args) == 2 and args[1] is Ellipsis else list(args)
        return len(arms) == len(value) and all(_has_type(a, v) for a, v in zip(arms, value))
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is type(None):
        return value is None
    return isinstance(value, hint) if isinstance(hint, type) else True


def _type_name(hint: Any) -> str:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in args)
    if origin is tuple:
        return f"a list of {_type_name(args[0])}" if len(args) == 2 and args[1] is Ellipsis else \
            f"a list of {len(args)} values ({', '.join(_type_name(a) for a in args)})"
    names = {float: "a finite number", int: "a whole number", bool: "true or false", type(None): "null"}
    return names.get(hint, getattr(hint, "__name__", str(hint)))


def config_to_json(cfg: Any) -> dict[str, Any]:
    """A frozen dataclass as a JSON-ready dict (tuples become lists, nested dataclasses become dicts)."""
    if not dataclasses.is_dataclass(cfg) or isinstance(cfg, type):
        raise TypeError(f"expected a dataclass instance, got {type(cfg).__name__}")
    return {f.name: _to_json_value(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}


def _to_json_value(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return config_to_json(value)
    if isinstance(value, (tuple, list)):
        return [_to_json_value(v) for v in value]
    return value


def config_from_json(cls: type[T], data: dict[str, Any]) -> T:
    """Rebuild ``cls`` from :func:`config_to_json` output; unknown keys or bad values raise one-line UserError.

    Missing keys take the dataclass defaults, so configs saved before a field was added still load.
    """
    if not isinstance(data, dict):
        raise UserError(f"{cls.__name__}: expected a JSON object, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise UserError(f"{cls.__name__}: unknown key(s) {', '.join(unknown)}; "
                        "the file was written by an incompatible version of insertnerf")
    kwargs = {name: _from_json_value(hints[name], value) for name, value in data.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as err:
        raise UserError(f"{cls.__name__}: invalid value: {err}") from None


def _from_json_value(hint: Any, value: Any) -> Any:
    """Convert a JSON value back to the annotated type (lists to tuples, dicts to nested dataclasses)."""
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint) and isinstance(value, dict):
        return config_from_json(hint, value)
    if origin is tuple and isinstance(value, list):
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_from_json_value(args[0], v) for v in value)
        if args and len(args) != len(value):
            raise UserError(f"expected {len(args)} values, got {len(value)}: {value}")
        return tuple(_from_json_value(a, v) for a, v in zip(args, value)) if args else tuple(value)
    if hint is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value
