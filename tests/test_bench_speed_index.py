"""benchmarks/speed_index.py: the machine's speed index is measured in a child process
and recorded as given; a missing script is recorded as not measured, with the reason."""

import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.speed_index import measure_speed_index, speed_index_line  # noqa: E402


def test_the_index_comes_from_a_child_process(tmp_path, monkeypatch):
    script = tmp_path / "index.py"
    # The child reports its own pid, so the test sees that it ran in another process.
    script.write_text("import json, os, sys\nprint('warming up')\n"
                      "print(json.dumps({'speed_index_s': 4.25, 'parts': {'pid': os.getpid(), "
                      "'argv': sys.argv[1:]}}))\n")  # fmt: skip
    monkeypatch.setenv("LUNAR_DRAKE_SPEED_INDEX", str(script))
    r = measure_speed_index(repeats=2)
    assert r["speed_index_s"] == 4.25 and r["script"] == str(script)
    assert r["parts"]["argv"] == ["--repeats", "2"]
    assert r["parts"]["pid"] != os.getpid()
    assert "4.250 s" in speed_index_line(r)
    json.dumps(r)  # goes into the benchmark's JSON as is


def test_a_missing_or_failing_script_is_recorded_as_not_measured(tmp_path, monkeypatch):
    monkeypatch.setenv("LUNAR_DRAKE_SPEED_INDEX", str(tmp_path / "absent.py"))
    r = measure_speed_index()
    assert r["speed_index_s"] is None and "not found" in r["error"]
    bad = tmp_path / "bad.py"
    bad.write_text("raise SystemExit('no numpy here')\n")
    monkeypatch.setenv("LUNAR_DRAKE_SPEED_INDEX", str(bad))
    r = measure_speed_index()
    assert r["speed_index_s"] is None and "no numpy here" in r["error"]
    assert speed_index_line(r).startswith("speed index: not measured")


def test_record_speed_index_adds_the_measurement_to_a_results_document(tmp_path, monkeypatch,
                                                                        capsys):  # fmt: skip
    from benchmarks.speed_index import record_speed_index

    script = tmp_path / "index.py"
    script.write_text("import json\nprint(json.dumps({'speed_index_s': 2.5, 'parts': {}}))\n")
    monkeypatch.setenv("LUNAR_DRAKE_SPEED_INDEX", str(script))
    doc = {"figure": 1.0}
    assert record_speed_index(doc) is doc
    assert doc["figure"] == 1.0 and doc["speed_index_s"] == 2.5
    assert doc["speed_index"]["script"] == str(script)
    assert "2.500 s" in capsys.readouterr().out


def test_a_benchmark_run_records_the_index_in_its_json(tmp_path, monkeypatch):
    from benchmarks import terramechanics

    script = tmp_path / "index.py"
    script.write_text("import json\nprint(json.dumps({'speed_index_s': 3.0, 'parts': {}}))\n")
    monkeypatch.setenv("LUNAR_DRAKE_SPEED_INDEX", str(script))
    out = tmp_path / "tm.json"
    assert terramechanics.main(["--calls", "5", "--wheels", "2", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["speed_index_s"] == 3.0 and doc["results"]


def test_every_benchmark_that_writes_json_records_the_speed_index():
    # Machines here differ by up to 3x from day to day (issue 29): a figure without the
    # index beside it cannot be compared with another day's.
    missing = []
    for path in sorted((ROOT / "benchmarks").glob("*.py")):
        text = path.read_text()
        if path.name in ("__init__.py", "speed_index.py") or "atomic_write_text(" not in text:
            continue
        if "measure_speed_index(" not in text and "record_speed_index(" not in text:
            missing.append(path.name)
    assert not missing, f"benchmarks writing JSON without the speed index: {missing}"
