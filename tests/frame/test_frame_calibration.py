"""Issue 63, point 2: the frame stage never turns a scan silently, turns a file away from its
own axis only on overwhelming evidence, and states a wrong call it cannot check as unsure."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from jointseg.frame import gravity, weigh
from jointseg.frame.decide import UP_UNSURE, decide_frame, rotation_to_z, up_warnings
from jointseg.frame.sources import MODERATE, SIGNED_AXES
from jointseg.scan import Scan
from jointseg.synth import make_room


@pytest.fixture(scope="module")
def room() -> Scan:
    return make_room(4201, points=40_000)


def _part(room: Scan, keep: np.ndarray) -> Scan:
    return Scan(room.xyz[keep], None if room.rgb is None else room.rgb[keep])


@pytest.mark.parametrize("cut", ["floor slice", "half room"])
def test_an_ambiguous_z_up_room_is_not_turned_silently(room, cut) -> None:
    z, x = room.xyz[:, 2], room.xyz[:, 0]
    keep = z < z.min() + 1.2 if cut == "floor slice" else x < np.median(x)
    frame = decide_frame(_part(room, keep))
    up = frame.report()["up"]
    assert up["file_axis"] == "+z" and up["turned"] == (up["axis"] != "+z")
    if up["turned"]:
        assert any("file's +z" in w and "--up +z" in w for w in frame.warnings)


def test_a_y_up_room_is_turned_with_a_warning_naming_the_files_axis(room) -> None:
    scan = replace(room, xyz=room.xyz @ rotation_to_z(gravity.AXES["+y"]))
    frame = decide_frame(scan)
    assert frame.up.axis == "+y" and frame.turned and frame.file_axis == "+z"
    assert frame.report()["up"]["turned"] is True
    warning = " ".join(frame.warnings)
    assert "file's +z" in warning and "+y" in warning and "--up +z" in warning
    assert f"{frame.up.confidence:.2f}" in warning


def test_a_clean_room_is_not_turned(room) -> None:
    frame = decide_frame(room)
    assert frame.up.axis == "+z" and not frame.turned
    assert not any("turned" in w for w in frame.warnings)


def _evidence(geometry_sure: float) -> weigh.Evidence:
    """A plain file (z up by default) whose geometry gives +z ``geometry_sure``."""
    prior = np.zeros(6)
    prior[SIGNED_AXES.index("+z")] = MODERATE
    return weigh.Evidence(prior, np.array([0.0, 0.0, 1.0]), np.array([0.5, 0.5, geometry_sure]),
                          room_like=True, camera_up=None)  # fmt: skip


def test_an_unchecked_call_on_an_unsure_geometry_is_stated_unsure() -> None:
    # the logit is sure of +z (the file's word and the axis step), the sign step only 0.88:
    # an upside-down delivery reads like this, so the call is forced to be stated unsure
    w = weigh.weigh(_evidence(0.88))
    assert w.best == "+z" and w.probability >= UP_UNSURE
    assert w.confidence < UP_UNSURE
    estimate = gravity.UpEstimate(gravity.AXES["+z"], "+z", 0.0, w.confidence, {})
    assert any("unsure" in m for m in up_warnings(estimate, "+z"))
    sure = weigh.weigh(_evidence(0.999))
    assert sure.confidence == sure.probability


def test_a_turn_needs_overwhelming_evidence() -> None:
    p = np.array([0.0, 0.0, 0.75, 0.0, 0.25, 0.0])  # +y 0.75 against the file's +z
    assert weigh.choose(p, "+z") == "+z"
    p = np.array([0.0, 0.0, 0.95, 0.0, 0.05, 0.0])
    assert weigh.choose(p, "+z") == "+y"


def _floor_only(scan: Scan) -> np.ndarray:
    return gravity.floor_only(gravity.frame_sample(scan.xyz - np.median(scan.xyz, axis=0)))


def test_a_floor_without_a_ceiling_is_found_along_its_up(room) -> None:
    assert room.labels is not None
    closed = _floor_only(room)
    assert closed.max() < weigh.FLOOR_ONLY  # a floor and its ceiling, walls on every side
    no_ceiling = _part(room, room.labels != 0)  # the ceiling left unscanned
    open_top = _floor_only(no_ceiling)
    assert SIGNED_AXES[int(np.argmax(open_top))] == "+z"
    assert open_top.max() >= weigh.FLOOR_ONLY
    sideways = replace(no_ceiling, xyz=no_ceiling.xyz @ rotation_to_z(gravity.AXES["-x"]))
    assert SIGNED_AXES[int(np.argmax(_floor_only(sideways)))] == "-x"


def test_a_floor_without_a_ceiling_elsewhere_makes_a_sure_call_unsure() -> None:
    # the geometry and the file agree on +z, surely; the scan's only floor faces +x
    floor_only = np.zeros(6)
    floor_only[SIGNED_AXES.index("+x")] = 0.13
    sure = replace(_evidence(0.999), floor_only=floor_only)
    w = weigh.weigh(sure)
    assert w.best == "+z" and w.probability >= UP_UNSURE
    assert w.floor_elsewhere == "+x" and w.confidence <= weigh.FLOOR_ELSEWHERE_CAP < UP_UNSURE
    estimate = gravity.UpEstimate(gravity.AXES["+z"], "+z", 0.0, w.confidence, {})
    (warning,) = up_warnings(estimate, "+z", w.floor_elsewhere)
    assert "unsure" in warning and "--up +x" in warning
    assert w.report()["floor_elsewhere"] == "+x"
    # the same floor along the axis decided, or in a single camera view, changes nothing
    along = replace(sure, floor_only=np.roll(floor_only, 4))
    assert weigh.weigh(along).confidence == weigh.weigh(along).probability
    camera = replace(sure, camera_up="+z")
    assert weigh.weigh(camera).floor_elsewhere is None
