#!/usr/bin/env bash
# The main job through the job service: start `jointseg serve` (API, worker, viewer) on the
# embedded default, submit a scan with `jointseg submit --wait`, fetch its result and report,
# then stop the service (Ctrl-C or SIGTERM does the same by hand).
#   usage: scripts/demo_service.sh SCAN OUT REPORT DATA_DIR [PORT]
set -euo pipefail
scan=$1 out=$2 report=$3 data=$4 port=${5:-8000}
bin=$(dirname "$0")/../.venv/bin
url="http://127.0.0.1:${port}"

"$bin/jointseg" serve --port "$port" --data-dir "$data" --workers 1 &
serve_pid=$!
stop() { kill -TERM "$serve_pid" 2>/dev/null || true; wait "$serve_pid" 2>/dev/null || true; }
trap stop EXIT

# wait until the API answers and a worker has announced itself
"$bin/python" - "$url" <<'PY'
import sys, time, httpx
url = sys.argv[1]
deadline = time.monotonic() + 180
while time.monotonic() < deadline:
    try:
        if httpx.get(f"{url}/healthz", timeout=5).json().get("workers"):
            sys.exit(0)
    except (httpx.HTTPError, ValueError):
        pass
    time.sleep(0.5)
sys.exit(f"the service at {url} did not become healthy")
PY

"$bin/jointseg" submit "$scan" --server "$url" --wait -o "$out" --report "$report"
echo "jobs: $url/v1/jobs  (API docs: $url/docs)"
