"""Issue 31: scans as users deliver them. Each test turns a synthetic room into a real-world
delivery (another up axis, a tilt, another unit, stray points, no colour) and checks that the
frame stage undoes it: the same labels as the clean room, the user's coordinates untouched."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

from jointseg.exceptions import ConfigError
from jointseg.frame import gravity
from jointseg.frame.decide import decide_frame, rotation_about, rotation_to_z
from jointseg.frame.params import FrameParams
from jointseg.frame.strays import find_strays
from jointseg.frame.units import units_from_scale
from jointseg.io import read_scan, write_scan
from jointseg.io.units import UNITS, unit_from_geokeys, unit_from_wkt
from jointseg.network.randlanet.backend import COLOUR_FREE_WEIGHTS
from jointseg.network.registry import REGISTRY
from jointseg.pipeline import PipelineConfig, load_predictor, run, segment_file
from jointseg.scan import Scan
from jointseg.synth import make_room

needs_weights = pytest.mark.skipif(
    not REGISTRY["randlanet"].bundled.is_file() or not COLOUR_FREE_WEIGHTS.is_file(),
    reason="the bundled RandLA-Net weights are not installed",
)

US_FT_WKT = (
    'PROJCS["NAD83 / California zone 3 (ftUS)",GEOGCS["NAD83",DATUM["North_American_Datum_1983",'
    'SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],'
    'UNIT["degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic_2SP"],'
    'UNIT["US survey foot",0.3048006096012192],AXIS["Easting",EAST],AXIS["Northing",NORTH]]'
)


def delivered(up: str) -> np.ndarray:
    """A proper rotation taking the room's +z to ``up``."""
    return rotation_to_z(gravity.AXES[up]).T


@pytest.fixture(scope="module")
def room() -> Scan:
    return make_room(3101, points=60_000)


@pytest.fixture(scope="module")
def predictor():
    return load_predictor(PipelineConfig().network)


@pytest.fixture(scope="module")
def level(room, predictor):
    return run(room, PipelineConfig(), predictor=predictor)


def moved(room: Scan, r: np.ndarray, scale: float = 1.0) -> Scan:
    return Scan(room.xyz @ r.T * scale, room.rgb, room.labels)


@pytest.mark.slow
def test_the_up_direction_of_synthetic_rooms_is_found_from_any_axis_and_tilt() -> None:
    """Without the network: the five ways a room arrives other than upside down are found;
    an upside-down file (rare, and worse to read wrongly) is turned only on strong evidence, and
    is otherwise kept with a warning or read right."""
    rng = np.random.default_rng(7)
    right, cases, tilt_errors, upside = 0, 0, [], []
    for seed in (3201, 3202, 3203, 3204):
        scan = make_room(seed, points=40_000, shape="L" if seed % 2 else "box")
        for up in gravity.AXES:
            tilt = rotation_about(np.array([*rng.normal(size=2), 0.0]), rng.uniform(0, 15))
            r = delivered(up) @ tilt
            frame = decide_frame(moved(scan, r), FrameParams(strays=False))
            if up == "-z":
                upside.append(frame.up.axis == up or bool(frame.warnings))
                continue
            cases += 1
            if frame.up.axis == up:
                right += 1
                true_up = r @ np.array([0.0, 0.0, 1.0])
                tilt_errors.append(np.degrees(np.arccos(np.clip(frame.up.up @ true_up, -1, 1))))
    assert right >= 0.85 * cases, (right, cases)
    assert np.median(tilt_errors) < 1.5, tilt_errors
    assert sum(upside) >= 3, upside


@pytest.mark.slow
@needs_weights
@pytest.mark.parametrize("up", ["+y", "-y", "+x", "-z"])
def test_another_up_axis_gives_the_level_labels(room, predictor, level, up) -> None:
    result = run(moved(room, delivered(up)), PipelineConfig(), predictor=predictor)
    assert result.frame is not None
    if up == "-z" and result.frame.up.axis == "+z":
        # upside down needs strong evidence to overturn the file's own z: kept, it must say so
        assert any("--up" in w for w in result.frame.warnings), result.frame.report()["up"]
        return
    assert result.frame.up.axis == up
    agree = np.mean(result.fused_labels == level.fused_labels)
    assert agree >= 0.9, (up, agree)


@pytest.mark.slow
@needs_weights
def test_a_15_degree_tilt_is_levelled_and_gives_the_level_labels(room, predictor, level) -> None:
    r = rotation_about(np.array([1.0, 0.4, 0.0]), 15.0)
    result = run(moved(room, r), PipelineConfig(), predictor=predictor)
    assert result.frame is not None
    assert abs(result.frame.up.tilt_degrees - 15.0) < 1.5
    assert result.frame.report()["up"]["levelled"]
    agree = np.mean(result.fused_labels == level.fused_labels)
    assert agree >= 0.9, agree


def test_a_level_metric_scan_is_left_as_it_is(room) -> None:
    frame = decide_frame(room)
    assert frame.identity
    assert frame.to_work(room.xyz) is room.xyz
    assert frame.units.unit == "m" and frame.up.axis == "+z"


@pytest.mark.parametrize("unit", ["m", "cm", "mm", "ft", "in"])
def test_each_unit_is_recognised_from_the_scale(room, unit) -> None:
    scan = moved(room, np.eye(3), 1.0 / UNITS[unit])
    frame = decide_frame(scan)
    assert frame.units.unit == unit
    assert frame.units.how.startswith("scale")


def test_units_from_scale_prefer_metres_for_a_tall_storey() -> None:
    assert units_from_scale(4.5).unit == "m"
    assert units_from_scale(2800.0).unit == "mm"
    assert units_from_scale(280.0).unit == "cm"
    assert units_from_scale(9.5).unit == "ft"
    assert units_from_scale(110.0).unit == "in"


@pytest.mark.slow
@needs_weights
def test_a_scan_in_millimetres_keeps_its_coordinates_and_the_metre_labels(
    room, predictor, level, tmp_path: Path
) -> None:
    source = tmp_path / "room_mm.ply"
    write_scan(moved(room, delivered("+y"), 1000.0), source)
    out = tmp_path / "out.ply"
    done = segment_file(source, out, PipelineConfig(), predictor=predictor, max_points=10**7)
    written, given = read_scan(out), read_scan(source)
    assert np.array_equal(written.xyz, given.xyz)  # bit-exact, in millimetres
    frame = done.report["frame"]
    assert frame["units"]["unit"] == "mm" and frame["up"]["axis"] == "+y"
    agree = np.mean(written.fields["fused_label"] == level.fused_labels)
    assert agree >= 0.9, agree


def _las_in_feet(path: Path, xyz_ft: np.ndarray, vlr: laspy.VLR) -> None:
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.full(3, 0.001)
    header.offsets = np.array([6_000_000.0, 2_000_000.0, 0.0])
    header.vlrs.append(vlr)
    las = laspy.LasData(header)
    las.x, las.y, las.z = (xyz_ft[:, i] + header.offsets[i] for i in range(3))
    las.write(path)


def test_a_las_file_in_us_survey_feet_is_read_as_feet_from_its_crs(room, tmp_path: Path) -> None:
    path = tmp_path / "survey.las"
    vlr = laspy.VLR("LASF_Projection", 2112, "OGC WKT", US_FT_WKT.encode() + b"\0")
    _las_in_feet(path, room.xyz / UNITS["us-ft"], vlr)
    scan = read_scan(path)
    assert scan.meta["units"] == "us-ft"
    frame = decide_frame(scan)
    assert frame.units.unit == "us-ft" and "CRS" in frame.units.how
    # the output keeps the input's grid, origin and CRS: coordinates come back unchanged
    out = tmp_path / "copy.las"
    write_scan(scan.with_fields(stray=frame.stray.astype(np.uint8)), out)
    header = laspy.read(out).header
    assert np.array_equal(header.scales, [0.001] * 3)
    assert np.array_equal(header.offsets, [6_000_000.0, 2_000_000.0, 0.0])
    assert any(v.record_id == 2112 for v in header.vlrs)
    assert np.array_equal(read_scan(out).xyz, scan.xyz)


def test_geotiff_keys_name_the_unit() -> None:
    # GeoKeyDirectory: version 1.1.0, 2 keys: ProjectedCSType (3072) = 2227, ProjLinearUnits = 9002
    keys = np.array([1, 1, 0, 2, 3072, 0, 1, 2227, 3076, 0, 1, 9002], dtype="<u2").tobytes()
    assert unit_from_geokeys(keys) == "ft"
    assert unit_from_wkt(US_FT_WKT) == "us-ft"
    wkt2 = (
        'PROJCRS["x",BASEGEOGCRS["NAD83",DATUM["d",ELLIPSOID["GRS 1980",6378137,298.257,'
        'LENGTHUNIT["metre",1]]]],CS[Cartesian,2],AXIS["e",east,LENGTHUNIT["foot",0.3048]]]'
    )
    assert unit_from_wkt(wkt2) == "ft"


def with_strays(room: Scan, share: float, seed: int = 0) -> tuple[Scan, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = int(share * len(room))
    lo, hi = room.xyz.min(axis=0), room.xyz.max(axis=0)
    centre = (lo + hi) / 2
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    half = (hi - lo) / 2
    # 2-10 m beyond the room's box in a random direction
    reach = np.max(np.abs(direction) / half, axis=1)
    xyz = centre + direction / reach[:, None] + direction * rng.uniform(2, 10, (n, 1))
    rgb = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    labels = np.full(n, -1, dtype=np.int32)
    assert room.rgb is not None and room.labels is not None
    scan = Scan(
        np.vstack([room.xyz, xyz]),
        np.vstack([room.rgb, rgb]),
        np.concatenate([room.labels, labels]),
    )
    added = np.zeros(len(scan), dtype=bool)
    added[len(room) :] = True
    return scan, added


def test_stray_points_are_found_and_only_they(room) -> None:
    scan, added = with_strays(room, 0.003)
    stray = find_strays(scan.xyz)
    assert stray[added].mean() >= 0.9
    assert stray[~added].mean() <= 0.005


@pytest.mark.slow
@needs_weights
def test_stray_points_do_not_change_the_rooms_labels(room, predictor, level) -> None:
    scan, added = with_strays(room, 0.003)
    result = run(scan, PipelineConfig(), predictor=predictor)
    assert result.stray[added].mean() >= 0.9
    agree = np.mean(result.fused_labels[~added] == level.fused_labels)
    assert agree >= 0.98, agree
    body = result.frame.report() if result.frame else {}
    assert body["stray_points"] == int(result.stray.sum())


@pytest.mark.slow
@needs_weights
@pytest.mark.parametrize("colour", ["none", "constant"])
def test_a_scan_without_colour_takes_the_colour_free_network(room, predictor, colour) -> None:
    rgb = None if colour == "none" else np.full_like(room.rgb, 128)
    scan = Scan(room.xyz, rgb, room.labels)
    result = run(scan, PipelineConfig(), predictor=predictor)
    assert result.frame is not None and result.frame.colour.kind == colour
    assert result.params["network"]["colour"] is False
    assert result.params["network"]["weights"] == str(COLOUR_FREE_WEIGHTS)
    kept = run(
        scan,
        PipelineConfig.model_validate({"network": {"colour_free": "off"}}),
        predictor=predictor,
    )
    assert kept.params["network"]["colour"] is True
    # with colour the colour network stays
    assert run(room, PipelineConfig(), predictor=predictor).params["network"]["colour"] is True


def test_dim_colour_is_brought_back_and_good_colour_left_alone(room) -> None:
    assert room.rgb is not None
    assert decide_frame(room).colour.gains is None
    dim = Scan(room.xyz, (room.rgb * 0.4).astype(np.uint8), room.labels)
    gains = decide_frame(dim).colour.gains
    assert gains is not None and np.all(gains > 1.5)


def test_the_user_overrides_the_decisions(room) -> None:
    frame = decide_frame(
        moved(room, np.eye(3), 1000.0), FrameParams(up="+x", units="m", strays=False)
    )
    assert frame.up.axis == "+x" and frame.up_how == "set by the user"
    assert frame.units.unit == "m" and frame.units.how == "set by the user"
    with pytest.raises(ValueError):
        PipelineConfig.model_validate({"frame": {"up": "up"}})


@pytest.mark.parametrize(
    "xyz",
    [
        np.zeros((5, 3)),
        np.c_[np.linspace(0, 1, 500), np.zeros(500), np.zeros(500)],
        np.c_[np.random.default_rng(0).random((800, 2)), np.zeros(800)],
    ],
    ids=["five-points", "collinear", "one-plane"],
)
def test_degenerate_scans_give_a_clear_error_or_labels(xyz, predictor) -> None:
    try:
        result = run(Scan(xyz), PipelineConfig(), predictor=predictor)
    except ConfigError as exc:
        assert "\n" not in str(exc)
    else:
        assert len(result.fused_labels) == len(xyz)


@pytest.mark.slow
@needs_weights
def test_a_tiled_run_takes_the_same_frame(room, predictor, tmp_path: Path) -> None:
    metric, added = with_strays(room, 0.003)
    scan = moved(metric, delivered("+y"), 1000.0)
    source = tmp_path / "big.ply"
    write_scan(scan, source)
    config = PipelineConfig()
    tiled = config.model_copy(
        update={"tiles": config.tiles.model_copy(update={"max_points": 25_000})}
    )
    whole = segment_file(
        source, tmp_path / "whole.ply", config, predictor=predictor, max_points=10**7
    )
    cut = segment_file(source, tmp_path / "tiles.ply", tiled, predictor=predictor, max_points=10**7)
    assert cut.tiles is not None and cut.tiles > 1
    assert (
        cut.report["frame"]["up"]["axis"] == "+y" and cut.report["frame"]["units"]["unit"] == "mm"
    )
    a, b = read_scan(tmp_path / "whole.ply"), read_scan(tmp_path / "tiles.ply")
    assert np.array_equal(b.xyz, read_scan(source).xyz)
    assert b.fields["stray"][added].mean() >= 0.9 and b.fields["stray"][~added].mean() < 0.005
    agree = np.mean(a.fields["fused_label"][~added] == b.fields["fused_label"][~added])
    assert agree >= 0.9, agree
    assert whole.metrics is not None and cut.metrics is not None
    assert abs(whole.metrics["fused"].miou - cut.metrics["fused"].miou) < 0.03


def test_a_slice_of_a_room_keeps_the_files_up(room) -> None:
    # the bottom metre of a room (like the S3DIS fragment): no ceiling, no storey to read
    low = room.subset(room.xyz[:, 2] < room.xyz[:, 2].min() + 1.0)
    frame = decide_frame(low)
    assert frame.up.axis == "+z" and not frame.levelled
    assert not frame.report()["up"]["evidence"]["room_like"]


@pytest.mark.slow
def test_millimetres_forced_as_metres_give_labels_and_a_warning(room, predictor) -> None:
    scan = moved(room, np.eye(3), 1000.0)
    config = PipelineConfig.model_validate({"frame": {"units": "m"}})
    result = run(scan, config, predictor=predictor)  # no IndexError from the plane fits
    assert len(result.fused_labels) == len(scan)
    assert result.frame is not None
    assert any("no indoor scan is" in w for w in result.frame.warnings)
