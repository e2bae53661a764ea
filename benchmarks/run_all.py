"""Run every benchmark script in this folder and collect their JSON into benchmarks/results/<host>.json."""

from __future__ import annotations

import json
import platform
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> int:
    results = {}
    for script in sorted(HERE.glob("bench_*.py")):
        print(f"== {script.name}", flush=True)
        r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True)
        if r.returncode != 0:
            print(r.stderr[-2000:], file=sys.stderr)
            results[script.stem] = {"error": r.stderr[-500:]}
            continue
        try:
            results[script.stem] = json.loads(r.stdout[r.stdout.index("{") :])
        except ValueError:
            results[script.stem] = {"raw": r.stdout[-2000:]}
        print(r.stdout)
    out = HERE / "results" / f"{platform.node() or 'host'}.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
