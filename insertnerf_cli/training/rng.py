"""Random-generator states as tensors, so a checkpoint stays loadable with ``torch.load(weights_only=True)``.

Exact resumption needs every generator a step touches: Python's ``random``, NumPy's global generator, torch's
CPU (and CUDA) generator, and the data sampler's own NumPy generator.
"""
from __future__ import annotations

import random

import numpy as np
import torch
from torch import Tensor

_WORD = 32  # PCG64's 128-bit integers are stored as four 32-bit words
_WORDS = 4


def capture_rng(data_rng: np.random.Generator, device: torch.device) -> dict[str, Tensor]:
    """Every generator's state as named tensors."""
    version, words, gauss = random.getstate()
    _, mt_keys, mt_pos, has_gauss, cached = np.random.get_state(legacy=True)
    data = data_rng.bit_generator.state
    states = {
        "python": torch.tensor([version, *words], dtype=torch.int64),
        "python_gauss": torch.tensor([] if gauss is None else [gauss], dtype=torch.float64),
        "numpy_keys": torch.from_numpy(mt_keys.astype(np.int64)),
        "numpy_meta": torch.tensor([mt_pos, has_gauss], dtype=torch.int64),
        "numpy_gauss": torch.tensor([cached], dtype=torch.float64),
        "torch": torch.get_rng_state(),
        "data": torch.tensor([*_split(data["state"]["state"]), *_split(data["state"]["inc"]),
                              data["has_uint32"], data["uinteger"]], dtype=torch.int64),
    }
    if device.type == "cuda":
        states["cuda"] = torch.cuda.get_rng_state(device)
    return states


def restore_rng(states: dict[str, Tensor], data_rng: np.random.Generator, device: torch.device) -> None:
    """Put every generator back in the state :func:`capture_rng` recorded."""
    python = [int(v) for v in states["python"].tolist()]
    gauss = states["python_gauss"].tolist()
    random.setstate((python[0], tuple(python[1:]), gauss[0] if gauss else None))
    meta = states["numpy_meta"].tolist()
    np.random.set_state(("MT19937", states["numpy_keys"].numpy().astype(np.uint32), int(meta[0]), int(meta[1]),
                         float(states["numpy_gauss"][0])))
    torch.set_rng_state(states["torch"].to(torch.uint8))
    data = [int(v) for v in states["data"].tolist()]
    data_rng.bit_generator.state = {
        "bit_generator": "PCG64",
        "state": {"state": _join(data[:_WORDS]), "inc": _join(data[_WORDS:2 * _WORDS])},
        "has_uint32": data[2 * _WORDS], "uinteger": data[2 * _WORDS + 1],
    }
    if device.type == "cuda" and "cuda" in states:
        torch.cuda.set_rng_state(states["cuda"].to(torch.uint8), device)


def _split(value: int) -> list[int]:
    """A 128-bit integer as four 32-bit words, least significant first."""
    mask = (1 << _WORD) - 1
    return [(value >> (_WORD * i)) & mask for i in range(_WORDS)]


def _join(words: list[int]) -> int:
    return sum(w << (_WORD * i) for i, w in enumerate(words))
