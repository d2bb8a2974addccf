"""benchmarks/world_model.py end to end on a tiny site: the site is synthesized in a child
process, the build timed in another, and the JSON holds what the docs quote."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_world_model_benchmark_writes_its_json(tmp_path):
    out = tmp_path / "bench.json"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "world_model.py"), "--size", "128",
           "--cache", str(tmp_path / "cache"), "--out", str(out)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert doc["size"] == 128 and doc["compress"] == "none"
    assert doc["seconds"] > 0.0
    # The build's own peak: a Python process with numpy, numba and GDAL, well under 4 GB.
    assert 50.0 < doc["peak_rss_mb"] < 4096.0
    assert 0.0 <= doc["psr_fraction"] <= 1.0
    assert "sun over a year" in doc["stage_seconds"]
    assert (tmp_path / "cache" / "site_128_0.04_0" / "site.json").is_file()
    assert "size  pixel m" in proc.stdout


def test_world_model_benchmark_refuses_a_bad_size_in_one_line(tmp_path):
    cmd = [sys.executable, str(ROOT / "benchmarks" / "world_model.py"), "--size", "100",
           "--cache", str(tmp_path / "cache")]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        "world_model.py: error: ConfigError: size_px = 100 must be a multiple of factor = 32"
    )
    assert not (tmp_path / "cache" / "site_100_0.04_0").exists()
