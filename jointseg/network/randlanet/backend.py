"""The RandLA-Net backend: jointseg's own checkpoints, bundled weights trained on S3DIS Area 6,
ScanNet and synthetic rooms (see :mod:`jointseg.network.randlanet.predict` for the inference).

Imports no torch: the registry reads this record to know the backend.
"""

from __future__ import annotations

from jointseg.network.backends import WEIGHTS_DIR, Backend
from jointseg.network.randlanet.params import RandLANetParams

#: The same network trained with colour withheld: taken automatically for scans without colour
#: (``network.colour_free``).
COLOUR_FREE_WEIGHTS = WEIGHTS_DIR / "randlanet_indoor_nocolour.pt"

BACKEND = Backend(
    name="randlanet",
    loader="jointseg.network.randlanet.predict:load_randlanet",
    fast_loader="jointseg.network.randlanet.compiled:load_compiled",
    card_reader="jointseg.network.randlanet.predict:read_randlanet_card",
    env="JOINTSEG_RANDLANET_WEIGHTS",
    where_to_get=(
        "train them with `jointseg train --data synth --out model.pt`, or convert Open3D-ML's "
        "randlanet_s3dis_202201071330utc.pth with `jointseg models import open3d-ml FILE`"
    ),
    bundled=WEIGHTS_DIR / "randlanet_indoor.pt",
    suffixes=(".pt", ".pth"),
    params=RandLANetParams,
    params_help="RandLA-Net's whole-scan inference (classes taken as absent)",
)
