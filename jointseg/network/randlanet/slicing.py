"""A narrow RandLA-Net that starts from a wide one's weights.

Copying each tensor's leading block is not enough: several layers read a concatenation (the
attentive pooling reads gathered features beside the position encoding, each decoder layer a
skip beside the upsampled features), and the narrow network's halves sit at other offsets
than the wide one's. Each kept channel is therefore mapped to its place in the wide layout, so
that the narrow network computes exactly what the wide one does on the kept channels.
"""

from __future__ import annotations

import re

import torch

from jointseg.exceptions import ConfigError
from jointseg.network.randlanet.model import RandLANet, RandLANetConfig, decoder_inputs

_POOL = re.compile(r"encoder\.(\d+)\.pool[12]\.(score|mlp\.conv)\.(weight|bias)$")
_DECODER = re.compile(r"decoder\.(\d+)\.conv\.weight$")


def concatenated(wide: tuple[int, ...], narrow: tuple[int, ...]) -> torch.Tensor:
    """Where a narrow concatenation's channels sit in the wide one: each part's leading
    channels, at that part's offset in the wide layout."""
    offsets = [0, *torch.tensor(wide).cumsum(0).tolist()[:-1]]
    return torch.cat([torch.arange(o, o + n) for o, n in zip(offsets, narrow, strict=True)])


def channel_maps(
    name: str, shape: tuple[int, ...], wide: RandLANetConfig, narrow: RandLANetConfig
) -> tuple[torch.Tensor, ...]:
    """For one tensor of the narrow network, the wide network's index along each axis."""
    maps = [torch.arange(n) for n in shape]
    if m := _POOL.match(name):
        i = int(m.group(1))
        inputs = concatenated((wide.d_out[i] // 2,) * 2, (narrow.d_out[i] // 2,) * 2)
        if m.group(2) == "score":  # the scores weigh the concatenation they read
            maps[0] = inputs
        if m.group(3) == "weight":
            maps[1] = inputs
    elif m := _DECODER.match(name):
        i = int(m.group(1))
        maps[1] = concatenated(decoder_inputs(wide)[i], decoder_inputs(narrow)[i])
    return tuple(maps)


def sliced_init(student: RandLANet, teacher: RandLANet) -> None:
    """Give ``student`` (the same layers, fewer channels) the teacher's weights on its kept
    channels: a narrow network that starts from what the wide one learnt rather than from
    noise."""
    source = teacher.state_dict()
    target = student.state_dict()
    for name, tensor in target.items():
        src = source.get(name)
        if src is None or src.dim() != tensor.dim():
            raise ConfigError(f"sliced init: the teacher has no tensor like {name!r}")
        if tensor.dim() == 0:
            target[name] = src.clone()
            continue
        if any(t > s for t, s in zip(tensor.shape, src.shape, strict=True)):
            raise ConfigError(f"sliced init: {name!r} is wider in the student than the teacher")
        maps = channel_maps(name, tuple(tensor.shape), teacher.config, student.config)
        block = src
        for axis, index in enumerate(maps):
            block = block.index_select(axis, index.to(src.device))
        target[name] = block.clone()
    student.load_state_dict(target)
