"""The span check the worker runs on a stored scan before the pipeline (server.limits): a real
file read chunk by chunk, refused with a message naming the span instead of a petabyte
allocation deep in the pipeline."""

from __future__ import annotations

from pathlib import Path

import pytest

from jointseg.exceptions import ScanFormatError
from jointseg.io import write_scan
from jointseg.scan import Scan
from jointseg.synth import make_room
from server.limits import check_file_span
from server.settings import Settings


@pytest.mark.parametrize("far", [1e18, 1e300])
def test_a_scan_spread_over_absurd_spans_is_refused_naming_the_span(
    tmp_path: Path, far: float
) -> None:
    room = make_room(0, points=2000)
    xyz = room.xyz.copy()
    xyz[7] = (far, 0.0, -far)
    path = write_scan(Scan(xyz=xyz, rgb=room.rgb), tmp_path / "far.las")
    limit = Settings().max_span
    with pytest.raises(ScanFormatError, match=r"^room\.las: its coordinates span .* along x"):
        check_file_span(path, "room.las", limit, 10_000)
    check_file_span(write_scan(room, tmp_path / "room.las"), "room.las", limit, 10_000)
