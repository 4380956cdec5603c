"""Quality presets: ``fast`` for previews and big floors, ``standard`` (the default), ``best``
for a user who can wait.

A preset is a set of defaults under the user's own settings: ``{"quality": "fast",
"geometry": {"ransac_iterations": 800}}`` takes fast's values except the one given. The
values were chosen on the tuning scans of ``bench/presets.py``, which prints what each preset
costs and gives.
"""

from __future__ import annotations

from typing import Any, Literal

Quality = Literal["fast", "standard", "best"]

#: What each preset sets, as a partial pipeline config.
PRESETS: dict[str, dict[str, Any]] = {
    # one pass: the network on a 5 cm grid (two thirds of the cells) with crops until each point
    # is seen about once, the geometry on coarser voxels with fewer RANSAC tries
    "fast": {
        "network": {"randlanet": {"coverage": 0.05, "grid": 0.05}},
        "geometry": {"voxel_factor": 5.0, "ransac_iterations": 300},
    },
    "standard": {},
    # every crop in four views, and every other network with weights averaged in
    "best": {"network": {"randlanet": {"views": 4}, "ensemble": True}},
}


def with_preset(data: dict[str, Any]) -> dict[str, Any]:
    """A raw pipeline config with its quality preset's values filled in under the user's."""
    quality = data.get("quality", "standard")
    preset = PRESETS.get(quality) if isinstance(quality, str) else None
    if not preset:
        return data  # standard, or a bad value the model's own check refuses
    return _merge(preset, data)


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out
