"""The documentation's pictures show today's viewer and job page, not an older one (issue 45,
point 6).

``bench/viewer_tour.py`` makes them from the product and records beside them the digest of the
code they show (:mod:`web.pictures`); once that code changes, this test fails until the tour is
run again. Every picture of the viewer and the job page the docs hold must be one the tour made.
"""

from __future__ import annotations

from pathlib import Path

from web.pictures import code_digest, code_files, read_record

ROOT = Path(__file__).resolve().parents[2]
#: The pictures of the viewer, the job page and the IFC model in the documentation.
SHOWN = ("docs/viewer.png", "docs/job_page.png", "docs/images/ifc_floor.png")
GLOBS = ("docs/images/viewer_*.png", "docs/images/job_page_*.png")


def test_the_pictures_were_made_from_the_code_of_today() -> None:
    record = read_record(ROOT)
    assert record["code_sha256"] == code_digest(ROOT), (
        "web/ changed since the documentation's pictures were made: run "
        ".venv/bin/python bench/viewer_tour.py --no-fps (it rewrites docs/images/pictures.json)"
    )


def test_every_picture_of_the_viewer_in_the_docs_is_one_the_tour_made() -> None:
    made = set(read_record(ROOT)["pictures"])  # type: ignore[arg-type]
    shown = set(SHOWN) | {p.relative_to(ROOT).as_posix() for g in GLOBS for p in ROOT.glob(g)}
    assert shown <= made, sorted(shown - made)
    assert all((ROOT / name).is_file() for name in made)


def test_the_digest_changes_with_any_file_of_the_code(tmp_path: Path) -> None:
    # a copy of web/ gives the same digest; one byte more in any file gives another
    for path in code_files(ROOT):
        copy = tmp_path / path.relative_to(ROOT)
        copy.parent.mkdir(parents=True, exist_ok=True)
        copy.write_bytes(path.read_bytes())
    assert code_digest(tmp_path) == code_digest(ROOT)
    page = tmp_path / "web" / "static" / "jobs.js"
    page.write_bytes(page.read_bytes() + b"\n")
    assert code_digest(tmp_path) != code_digest(ROOT)
