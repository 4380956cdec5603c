"""Model cards without the paths of the machine that made the weights (issue 69): every path is
written as its last part, by the one writer of checkpoints, so no new card carries one."""

from __future__ import annotations

from pathlib import Path

import torch

from jointseg.network.cards import machine_paths, portable_card, portable_text
from jointseg.network.randlanet.checkpoint import load_checkpoint, save_checkpoint
from jointseg.network.randlanet.model import RandLANet, RandLANetConfig


def test_a_path_of_the_machine_becomes_its_last_part() -> None:
    said = "24 labelled scans from /work/shared/data/s3dis_area6 (area6_office_1)"
    assert portable_text(said) == "24 labelled scans from s3dis_area6 (area6_office_1)"
    command = "train --data a6=/work/shared/data/s3dis_area6:0.5 --init ~/models/base.pt"
    assert portable_text(command) == "train --data a6=s3dis_area6:0.5 --init base.pt"
    assert portable_text("every scan of ../../shared/data/") == "every scan of data"


def test_what_is_no_machine_path_stays() -> None:
    for text in (
        "features = [x - crop mean x, r/255, g/255, b/255]",
        "see https://github.com/QingyongHu/RandLA-Net",
        "S3DIS/ScanNet, temperature 0.5 / 2",
        "--out runs/cpu_bg/nocolour.pt --data .gpu/data",
    ):
        assert portable_text(text) == text and not machine_paths(text)


def test_a_card_is_made_portable_through_and_through() -> None:
    card = {"data": "/a/b/c", "sources": {"/d/e": 0.5}, "runs": ["../f/g.pt", 3, None]}
    assert machine_paths(card) == ["/a/b/c", "/d/e", "../f/g.pt"]
    assert portable_card(card) == {"data": "c", "sources": {"e": 0.5}, "runs": ["g.pt", 3, None]}


def test_a_checkpoint_is_written_with_a_portable_card(tmp_path: Path) -> None:
    torch.manual_seed(0)
    model = RandLANet(RandLANetConfig(num_points=4096))
    folder = tmp_path / "data" / "rooms"
    card = {"data": f"2 labelled scans from {folder}", "train_config": {"bank": str(folder)}}
    save_checkpoint(tmp_path / "net.pt", model, card)
    written = load_checkpoint(tmp_path / "net.pt")[1]
    assert written["data"] == "2 labelled scans from rooms"
    assert written["train_config"]["bank"] == "rooms" and not machine_paths(written)
