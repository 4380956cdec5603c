"""Error messages and reports name the user's file, never a path on the server."""

from __future__ import annotations

import json
from pathlib import Path

from server.messages import public_message, public_report, public_report_bytes


def test_public_messages_name_the_users_file_not_the_server_path(tmp_path: Path) -> None:
    stored = tmp_path / "jobs" / ("0" * 32) / "upload.ply"
    exc = ValueError(f"{stored}: bad header (in {stored})")
    message = public_message(exc, stored, "room.ply")
    assert message == "room.ply: bad header (in room.ply)"
    assert str(tmp_path) not in message


def test_a_report_names_the_weights_file_not_its_path_on_the_server(tmp_path: Path) -> None:
    weights = "/srv/venv/lib/python3.11/site-packages/jointseg/network/weights/randlanet_indoor.pt"
    body = {
        "input": "room.ply",
        "params": {"network": {"weights": weights, "networks": ["randlanet"]}},
        "members": [{"weights": "C:\\models\\dgcnn.pt"}, {"weights": "~/w/x.pt"}],
        "note": "a sentence naming /etc/hostname stays a sentence",
        "points": 3,
    }
    public = public_report(body)
    assert public["params"]["network"] == {
        "weights": "randlanet_indoor.pt",
        "networks": ["randlanet"],
    }
    assert public["members"] == [{"weights": "dgcnn.pt"}, {"weights": "x.pt"}]
    assert public["input"] == "room.ply" and public["points"] == 3
    assert public["note"] == body["note"]
    stored = tmp_path / "report.json"
    stored.write_text(json.dumps(body))
    assert json.loads(public_report_bytes(stored)) == public


def test_a_message_is_one_line_and_names_no_other_server_path(tmp_path: Path) -> None:
    """Whatever a loader's message carries besides the upload (the weights' path on the server,
    a library's source path, its text over several lines) reaches the client as file names on
    one line."""
    stored = tmp_path / "upload.ply"
    weights = tmp_path / "weights" / "mine.pt"
    exc = ValueError(
        f"{stored}: read with {weights}\n  at /project/libE57Format/src/CheckedFile.cpp(699)\n"
        "tile 3/8, see https://errors.pydantic.dev/2.14/v/x"
    )
    message = public_message(exc, stored, "room.ply")
    assert message == (
        "room.ply: read with mine.pt at CheckedFile.cpp(699) tile 3/8, see "
        "https://errors.pydantic.dev/2.14/v/x"
    )
    named = public_message(exc, stored, "room.ply", {str(weights): "team/mine.pt"})
    assert named.startswith("room.ply: read with team/mine.pt at ")
