"""The DGCNN backend: dgcnn.pytorch's published S3DIS weights (``model_i.t7``), with no bundled
weights (``jointseg models pull dgcnn-s3dis-5`` fetches the default ones); the inference is in
:mod:`jointseg.network.dgcnn.predict`.

Imports no torch: the registry reads this record to know the backend.
"""

from __future__ import annotations

from jointseg.network import published
from jointseg.network.backends import Backend
from jointseg.network.dgcnn.params import DGCNNParams

ENV = "JOINTSEG_DGCNN_WEIGHTS"

BACKEND = Backend(
    name="dgcnn",
    loader="jointseg.network.dgcnn.predict:load_dgcnn",
    card_reader="jointseg.network.dgcnn.predict:read_dgcnn_card",
    env=ENV,
    where_to_get=(
        f"run `jointseg models pull {published.DEFAULT_DGCNN}` (or dgcnn-s3dis-1 ... -6: model N "
        f"leaves S3DIS Area N out), or pass a file with --weights or set {ENV}"
    ),
    params=DGCNNParams,
    params_help="DGCNN's blocks and room normalisation",
    published=published.DEFAULT_DGCNN,
    suffixes=(".t7",),
)
