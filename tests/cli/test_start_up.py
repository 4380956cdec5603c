"""What `jointseg segment` imports before its work starts: not the job service's HTTP client, not
open3d's Plotly/Dash viewer; and open3d without its viewer still has the viewer on first use."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from jointseg.io import write_scan
from jointseg.synth import make_room

#: fresh interpreters that import torch and open3d: seconds each, not for `make test-fast`
pytestmark = pytest.mark.slow

#: Modules `jointseg segment` has no use for.
UNUSED = ("httpx", "plotly", "dash")


def _python(code: str) -> Any:
    """The last line ``code`` prints in a fresh interpreter, as JSON."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_segment_imports_no_http_client_and_no_viewer(tmp_path: Path, random_weights) -> None:
    source, output, report = tmp_path / "room.ply", tmp_path / "out.ply", tmp_path / "r.json"
    write_scan(make_room(3, points=5_000), source)
    args = ["segment", str(source), "-o", str(output), "--report", str(report)]
    args += ["--weights", str(random_weights)]
    code = (
        "import json, sys\n"
        "from jointseg.cli.app import main\n"
        "try:\n"
        f"    main({args!r})\n"
        "except SystemExit as exc:\n"
        "    assert not exc.code, exc.code\n"
        f"print(json.dumps([m for m in {UNUSED!r} if m in sys.modules]))"
    )
    assert _python(code) == []
    assert output.is_file()
    assert json.loads(report.read_text())["timings_s"]["load_network"] > 0


def test_open3d_without_its_viewer_still_has_it_on_first_use() -> None:
    code = (
        "import json, sys\n"
        "import numpy as np\n"
        "from jointseg.lazy import import_open3d\n"
        "o3d = import_open3d()\n"
        "import open3d\n"
        "assert open3d is o3d\n"
        "before = [m for m in ('plotly', 'dash') if m in sys.modules]\n"
        "cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.eye(3)))\n"
        "assert len(cloud.points) == 3\n"
        "assert callable(o3d.visualization.draw_geometries)\n"
        "from open3d.visualization import draw_plotly, rendering\n"
        "import open3d.visualization as vis\n"
        "assert vis is o3d.visualization and callable(draw_plotly) and rendering\n"
        "print(json.dumps([before, 'plotly' in sys.modules]))"
    )
    assert _python(code) == [[], True]
