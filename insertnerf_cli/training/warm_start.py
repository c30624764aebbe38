"""Start a model from the weights of a checkpoint with another sample count (``train --init``).

A new configuration that changes only how many samples a ray gets (the `fast` one: 32+16 instead of 64+64) keeps
every tensor's shape except the few that act along the sample axis: the HyperNet's sample-mixing linear
(``mix.weight`` [O, S]) and the sampling filter's adjacency factors (``to_nodes`` [N, S], ``from_nodes`` [S, N]).
Those are resampled along that axis (area averaging, like resizing a 1-D signal), everything else is copied, so
the new model starts where the trained one is instead of at random.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from insertnerf_cli.errors import UserError
from insertnerf_cli.model.checkpoint import Checkpoint

# The tensors whose sample axis sums over the samples (its entries shrink as samples get denser), by name suffix.
_SUMS_OVER_SAMPLES = ("mix.weight", "to_nodes")
# ... and the one that has one row per sample (its entries keep their size).
_PER_SAMPLE = ("from_nodes",)
# Tensors added by a model switch and initialised so that the model starts as one without them (zeros): a
# checkpoint from before the switch lacks them, and they keep their initial values.
_NEUTRAL_ADDITIONS = ("dynamic_deviation.weight",)


@dataclass(frozen=True)
class WarmStart:
    """What ``warm_start`` did: tensors copied as they were, and tensors resampled along the sample axis."""

    copied: int
    resampled: int


def warm_start(model: nn.Module, checkpoint: Checkpoint) -> WarmStart:
    """Load ``checkpoint``'s weights into ``model``, resampling sample-axis tensors whose sample count differs.

    A separate fine head missing from a shared-head checkpoint starts as a copy of its coarse head, and a NeRF++
    background head missing from a NeRF checkpoint as a copy of its fine head (_background_from_foreground); a
    neutral
    addition (the visibility cue's zero weights) missing from it keeps its initial value. Any other
    difference (a width, a layer, a name) is a UserError: that is not the same network with other samples.
    """
    own = model.state_dict()
    theirs = dict(checkpoint.model_state)
    for name in own:
        if name.startswith("fine_head.") and name not in theirs:
            theirs[name] = theirs.get("coarse_head." + name.removeprefix("fine_head."))
    for name in own:
        if name.startswith("background_head.") and name not in theirs:
            theirs[name] = _background_from_foreground(name, own[name], theirs, model)
    for name in own:
        if name.endswith(_NEUTRAL_ADDITIONS) and name not in theirs:
            theirs[name] = own[name]
    missing = sorted(n for n in own if theirs.get(n) is None)
    if missing:
        raise UserError(f"--init {checkpoint.path} lacks {len(missing)} tensors of this model (e.g. {missing[0]!r}): "
                        "it has another architecture; only the sample counts may differ.")
    state: dict[str, Tensor] = {}
    resampled = 0
    for name, target in own.items():
        source = theirs[name]
        if source.shape != target.shape:
            source = _resample(name, source, target.shape, checkpoint)
            resampled += 1
        state[name] = source.to(target.dtype)
    model.load_state_dict(state)
    return WarmStart(copied=len(state) - resampled, resampled=resampled)


# The first geometry layer's HyperNet makes one row of weights per input of the positional encoding.
_READS_POSITION = ("conditioners.0.weights.features.weight", "conditioners.0.weights.features.bias")


def _background_from_foreground(name: str, target: Tensor, theirs: dict[str, Tensor], model: nn.Module) -> Tensor | None:
    """The fine head's tensor for the background head's ``name``: the rows that read the positional encoding of
    x, y, z moved to those of the inverted sphere's first three coordinates (its direction), the inverse
    distance's rows zero (unread at first); None where the fine head has no such tensor."""
    source = theirs.get("fine_head." + name.removeprefix("background_head."), theirs.get(
        "coarse_head." + name.removeprefix("background_head.")))
    if source is None or not name.endswith(_READS_POSITION) or source.shape[0] == target.shape[0]:
        return source
    freqs = model.config.pe_freqs_pos
    if target.shape[0] != 4 * (1 + 2 * freqs) or source.shape[0] != 3 * (1 + 2 * freqs):
        raise UserError(f"--init: {name!r} does not read a {freqs}-frequency positional encoding")
    placed = torch.zeros((target.shape[0], *source.shape[1:]), dtype=source.dtype)
    for position in range(source.shape[0]):  # gamma(x) = [x, sin(2^k x), cos(2^k x)], k-major, 3 -> 4 per k
        block, dim = divmod(position, 3)
        placed[block * 4 + dim] = source[position]
    return placed


def _resample(name: str, source: Tensor, shape: torch.Size, checkpoint: Checkpoint) -> Tensor:
    """``source`` resized to ``shape`` along its sample axis (the last of [O, S] or [N, S]; the first of [S, N])."""
    if name.endswith(_SUMS_OVER_SAMPLES) and source.shape[:-1] == shape[:-1]:
        rows = source
    elif name.endswith(_PER_SAMPLE) and source.shape[1:] == shape[1:]:
        rows = source.T
    else:
        raise UserError(f"--init {checkpoint.path}: {name!r} is {tuple(source.shape)} there and {tuple(shape)} "
                        "here; only the sample counts may differ between the checkpoint and the new model.")
    old, new = rows.shape[-1], (shape[-1] if rows is source else shape[0])
    resized = F.interpolate(rows[None].float(), size=new, mode="linear" if new > old else "area",
                            align_corners=False if new > old else None)[0]
    if rows is source:
        return resized * (old / new)  # a sum over S samples keeps its value over the new count
    return resized.T.contiguous()
