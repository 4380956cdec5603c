"""What a user may tell the frame stage instead of letting it decide from the scan."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

UpChoice = Literal["auto", "+z", "-z", "+y", "-y", "+x", "-x"]
UnitsChoice = Literal["auto", "m", "cm", "mm", "ft", "us-ft", "in"]


class FrameParams(BaseModel):
    """How the scan is put into the frame the network and the geometry expect (z up, metres,
    stray points set aside, colour as trained on); outputs keep the user's coordinates.

    Examples
    --------
    ``{"up": "+y", "units": "mm"}`` for a glTF-style export in millimetres.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    up: UpChoice = Field(
        "auto",
        description="The file axis that points up; auto: from the scan's floor, ceiling and walls.",
    )
    level: bool = Field(
        True,
        description="Correct a residual tilt (up to ~20 degrees) from the floor's and ceiling's "
        "normals; tilts under 1 degree are left alone.",
    )
    units: UnitsChoice = Field(
        "auto",
        description="Length unit of the coordinates; auto: the file's CRS where it names one "
        "(LAS/LAZ; E57 is metres), else the scan's own storey height.",
    )
    strays: bool = Field(
        True,
        description="Set aside points far from the scan's bulk (returns through windows, off "
        "mirrors) so they move no normalisation; they still get labels and stray=1.",
    )
    colour: bool = Field(
        True,
        description="Bring exposure and white balance within what the network was trained on "
        "when the scan is far outside it.",
    )
