"""Error messages name the user's file, never the stored upload's path on the server."""

from __future__ import annotations

from pathlib import Path

from server.messages import public_message


def test_public_messages_name_the_users_file_not_the_server_path(tmp_path: Path) -> None:
    stored = tmp_path / "jobs" / ("0" * 32) / "upload.ply"
    exc = ValueError(f"{stored}: bad header (in {stored})")
    message = public_message(exc, stored, "room.ply")
    assert message == "room.ply: bad header (in room.ply)"
    assert str(tmp_path) not in message
