"""Parameters of the geometric segmentation, and how unset ones are derived from the scan.

Every distance threshold left as ``None`` becomes a multiple of the scan's median point spacing
and every colour threshold a multiple of its measured colour noise, so one default works on
dense and sparse scans (the paper tunes them per scene). Any of them can be set by hand.

The voxel size and the plane tolerance follow the spacing only up to :data:`SPARSE_SPACING`: a
scan sampled more thinly than that (a room thinned to one point per 3.3 cm, a far-range scan) is
sparser, not noisier, and coarser voxels and thicker planes would merge the objects on a wall
into it and each other (on the 15 tuning rooms of S3DIS thinned to 3.3 cm, segment purity 0.895
without the cap, 0.911 with it, against 0.939 for the rooms as scanned). The cap lies above the
RGB-D reconstructions' spacing (ScanNet's tuning scans: 1.6 to 2.0 cm), whose surfaces are
noisy as well as sparse: a cap at 1.6 cm moved their rooms' floor areas further from the truth.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, PositiveInt

#: The largest spacing (m) the voxel size and the plane tolerance grow with.
SPARSE_SPACING = 0.02


def detail_spacing(spacing: float) -> float:
    """The spacing the voxel size and plane tolerance are multiples of: the scan's own, at
    most :data:`SPARSE_SPACING`."""
    return min(spacing, SPARSE_SPACING)


class GeometryParams(BaseModel):
    """Thresholds of §2.2 (names after the paper where it names them); lengths in metres,
    colour distances in 8-bit RGB units (Euclidean)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # -- alignment (beyond the paper: any yaw) -------------------------------------------
    align: bool = Field(
        True,
        description="Rotate about z to the room's dominant wall directions "
        "before the bounding-box step.",
    )
    structure: bool = Field(
        True,
        description="Read floor, ceiling and walls from the segments' own geometry (no labels), "
        "as evidence the fusion vote weighs against the network's labels.",
    )
    voxel_factor: float = Field(
        2.5,
        ge=0,
        description="Segment voxel centroids of this many point spacings (at most "
        f"{SPARSE_SPACING} m each), then give every point its voxel's segment (beyond the "
        "paper: speed); 0 works on every point.",
    )
    # -- multi-level plane extraction (§2.2.1) ---------------------------------------------
    face_distance: PositiveFloat | None = Field(
        None,
        description="T: points within T of a bounding-box face form that face's set "
        "(eq. 3-4). Default: 12 x spacing, at least 0.08 m.",
    )
    ransac_iterations: PositiveInt = Field(1000, description="Z: RANSAC iterations per face set.")
    plane_distance: PositiveFloat | None = Field(
        None,
        description="sigma: RANSAC inlier distance to a plane. Default: 2.5 x spacing "
        f"(at most {SPARSE_SPACING} m), at least 0.015 m.",
    )
    max_plane_tilt_deg: float = Field(
        15.0, ge=0, le=90, description="A face's plane may tilt at most this from the face."
    )
    ransac_sample: PositiveInt = Field(
        4000, description="Points a RANSAC hypothesis is scored on before refinement."
    )
    min_face_points: PositiveInt = Field(
        200, description="A face set with fewer points yields no main plane."
    )
    # -- further planes (beyond the paper: L-shaped rooms, whole floors) -------------------
    extra_planes: bool = Field(
        True,
        description="Extract further large vertical and horizontal planes after the six box faces.",
    )
    min_wall_area: PositiveFloat = Field(
        2.0, description="Least area (m^2) of a further vertical plane."
    )
    min_wall_height_ratio: float = Field(
        0.6,
        gt=0,
        le=1,
        description="A further vertical plane must span this share of the "
        "floor-to-ceiling height (walls do, furniture does not).",
    )
    min_floor_area: PositiveFloat = Field(
        4.0, description="Least area (m^2) of a further horizontal plane."
    )
    min_plane_fill: float = Field(
        0.3,
        gt=0,
        le=1,
        description="Least share of a further plane's footprint cells that "
        "hold points (inlier density).",
    )
    plane_normal_deg: float = Field(
        90.0,
        gt=0,
        le=90,
        description="A main-plane point whose normal leans more than this (degrees) from its "
        "plane's leaves the plane for the clustering (objects touching a plane are not of "
        "it); 90 keeps every inlier, as the paper.",
    )
    # -- Euclidean clustering (§2.2.2) -------------------------------------------------------
    cluster_distance: PositiveFloat | None = Field(
        None, description="d_th: Euclidean cluster tolerance. Default: 3 x spacing."
    )
    adaptive_radius: float = Field(
        2.5,
        ge=0,
        description="Where points are sparser than d_th assumes (density falls with "
        "range), neighbours within this multiple of the local spacing also connect; 0 keeps "
        "PCL's fixed tolerance.",
    )
    neighbours: PositiveInt = Field(
        6, description="K: neighbours searched per point (clustering and region growing)."
    )
    # -- colour region growing (§2.2.3) ----------------------------------------------------
    colour_smoothing: bool = Field(
        True,
        description="Average each point's colour over its neighbours before region "
        "growing (beyond the paper: texture noise otherwise swamps surface contrast).",
    )
    point_colour_threshold: PositiveFloat | None = Field(
        None,
        description="Neighbouring points join a region when their colours differ by "
        "less. Default: 2.5 x colour noise.",
    )
    region_colour_threshold: PositiveFloat | None = Field(
        None,
        description="Neighbouring regions merge when their mean colours differ by less. "
        "Default: 4 x colour noise.",
    )
    colour_scale: PositiveFloat = Field(
        1.0,
        description="Multiplies the derived colour thresholds (below 1: more, purer regions).",
    )
    region_normal_deg: float = Field(
        90.0,
        gt=0,
        le=90,
        description="Neighbouring points whose normals differ by more (degrees) do not join "
        "one region (a crease between two surfaces); 90 grows on colour alone, as the paper.",
    )
    min_region_points: PositiveInt | None = Field(
        None,
        description="Regions (and clusters) smaller than this are merged into their "
        "nearest region. Default: max(30, N / 20000).",
    )


class ResolvedGeometryParams(GeometryParams):
    """Parameters with every adaptive default filled in, plus what they were derived from."""

    spacing: float
    colour_noise: float | None
    yaw_deg: float
    face_distance: PositiveFloat
    plane_distance: PositiveFloat
    cluster_distance: PositiveFloat
    point_colour_threshold: PositiveFloat | None
    region_colour_threshold: PositiveFloat | None
    min_region_points: PositiveInt


def resolve(
    params: GeometryParams,
    *,
    n_points: int,
    spacing: float,
    colour_noise: float | None,
    yaw_deg: float,
) -> ResolvedGeometryParams:
    """Fill unset thresholds from the scan's spacing (m) and colour noise (RGB units)."""
    s = max(spacing, 1e-4)
    noise = None if colour_noise is None else max(colour_noise, 1.0)
    values = params.model_dump()
    values.update(
        spacing=spacing,
        colour_noise=colour_noise,
        yaw_deg=yaw_deg,
        face_distance=params.face_distance or max(12 * s, 0.08),
        plane_distance=params.plane_distance or max(2.5 * detail_spacing(s), 0.015),
        cluster_distance=params.cluster_distance or 3 * s,
        point_colour_threshold=params.point_colour_threshold
        or (None if noise is None else 2.5 * params.colour_scale * noise),
        region_colour_threshold=params.region_colour_threshold
        or (None if noise is None else 4 * params.colour_scale * noise),
        min_region_points=params.min_region_points or max(30, n_points // 20_000),
    )
    return ResolvedGeometryParams(**values)
